"""Detector kernels: box shrink, cloud sampling, robust centre, colour blobs, detect()."""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from thinkfast.contract.detection import Detection, parse_detection
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.perception.boxes import Box
from thinkfast.perception.cloud import (
    Centre,
    box_points,
    centre,
    centre_ray,
    shrink_box,
    shrink_fraction,
)
from thinkfast.perception.colour import find_blobs
from thinkfast.perception.config import CloudConfig, ColourConfig, DetectConfig, ShrinkConfig
from thinkfast.perception.detect import Found, Miss, detect, detection_payload
from thinkfast.perception.frame import encode_frame, parse_frame

SHRINK = ShrinkConfig()
CLOUD = CloudConfig()
F = 532.0
W, H = 1280, 720


def _box_ratio(depth: float) -> float:
    """Box area / image area of a 67 mm ball at ``depth`` at HD720."""
    d_px = 2 * 0.0335 * F / depth
    return d_px * d_px / (W * H)


@pytest.mark.parametrize(("depth", "lo", "hi"), [(7.0, 0.04, 0.06), (8.0, 0.04, 0.06)])
def test_far_boxes_shrink_by_about_5_percent(depth, lo, hi):
    assert lo <= shrink_fraction(_box_ratio(depth), SHRINK) <= hi


@pytest.mark.parametrize("depth", [0.5, 0.7, 1.0])
def test_close_boxes_shrink_by_about_28_percent(depth):
    assert 0.25 <= shrink_fraction(_box_ratio(depth), SHRINK) <= 0.30


def test_shrink_grows_monotonically_with_box_area_between_its_asymptotes():
    ratios = np.logspace(-7, 0, 200)
    s = np.array([shrink_fraction(r, SHRINK) for r in ratios])
    assert (np.diff(s) > 0).all()
    assert SHRINK.far <= s.min() and s.max() <= SHRINK.near
    assert shrink_fraction(SHRINK.mid_area, SHRINK) == pytest.approx(
        0.5 * (SHRINK.far + SHRINK.near)
    )


def test_shrunk_box_keeps_its_centre_and_at_least_a_pixel():
    b = shrink_box((100, 200, 140, 230), (W, H), SHRINK)
    assert (b[0] + b[2]) / 2 == pytest.approx(120) and (b[1] + b[3]) / 2 == pytest.approx(215)
    s = 1 - shrink_fraction(40 * 30 / (W * H), SHRINK)
    assert b[2] - b[0] == pytest.approx(40 * s) and b[3] - b[1] == pytest.approx(30 * s)
    tiny = shrink_box((10, 10, 10.5, 10.5), (W, H), SHRINK)
    assert tiny[2] - tiny[0] == pytest.approx(1.0)


def test_box_points_map_image_boxes_onto_a_half_resolution_roi_cloud():
    xyz = np.zeros((10, 20, 3), np.float32)
    xyz[..., 0] = np.arange(20)[None, :]  # x holds the cloud column, y the row
    xyz[..., 1] = np.arange(10)[:, None]
    roi = (100, 50, 40, 20)  # cloud pixel (i, j) covers image pixels 100 + 2j.., 50 + 2i..
    pts = box_points(xyz, roi, (110, 56, 114, 60))
    assert sorted(set(pts[:, 0])) == [5, 6] and sorted(set(pts[:, 1])) == [3, 4]
    assert len(box_points(xyz, roi, (0, 0, 50, 40))) == 0  # outside the ROI
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True  # image pixel (110, 56): cloud cell (3, 5) only
    pts = box_points(xyz, roi, (110, 56, 114, 60), mask=mask, mask_origin=(110, 56))
    assert pts.tolist() == [[5.0, 3.0, 0.0]]
    assert box_points(xyz, roi, (110, 56, 114, 60), scale=1e-3)[:, 0].max() == pytest.approx(6e-3)


def _sphere_points(c, n=400, r=0.0335, seed=0):
    """Points on the visible cap of a sphere centred at ``c`` (camera frame), as a camera sees."""
    rng = np.random.default_rng(seed)
    c = np.asarray(c, float)
    u = c / np.linalg.norm(c)
    a = np.cross(u, [0, 0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    rho = r * np.sqrt(rng.random(n)) * 0.95
    phi = rng.uniform(0, 2 * np.pi, n)
    lat = rho[:, None] * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)
    return c + lat - np.sqrt(r * r - rho * rho)[:, None] * u


@pytest.mark.parametrize("c", [(0.8, 0.1, -0.05), (3.0, -0.9, 0.6), (8.0, 1.0, 0.5)])
def test_centre_of_exact_sphere_points_is_the_sphere_centre(c):
    got = centre(_sphere_points(c), np.asarray(c) / np.linalg.norm(c), F, CLOUD)
    assert isinstance(got, Centre)
    np.testing.assert_allclose(got.position, c, atol=1e-9)
    assert got.n_valid == got.n_inliers == 400 and got.spread < 1e-9 and got.confidence > 0.95


def test_centre_prefers_the_ball_over_more_numerous_scene_points_behind_it():
    c = np.array([8.5, 0.2, 0.3])
    ball = _sphere_points(c, n=6)
    wall = np.array([[12.0, 0.21, 0.31]] * 10) + np.random.default_rng(1).normal(0, 0.1, (10, 3))
    got = centre(np.vstack([wall, ball]), c / np.linalg.norm(c), F, CLOUD)
    assert isinstance(got, Centre) and np.linalg.norm(got.position - c) < 1e-6
    assert got.n_valid == 16 and got.n_inliers == 6


def test_centre_ignores_non_finite_points_and_says_why_there_is_none():
    ray = np.array([1.0, 0, 0])
    nan = np.full((50, 3), np.nan)
    assert centre(nan, ray, F, CLOUD) == "no_depth"
    pts = np.vstack([nan, _sphere_points((2.0, 0, 0), n=5)])
    pts[0] = np.inf
    assert isinstance(centre(pts, ray, F, CLOUD), Centre)
    assert centre(_sphere_points((25.0, 0, 0)), ray, F, CLOUD) == "out_of_range"


def test_centre_ray_points_through_the_pixel():
    ray = centre_ray(639.5 + 53.2, 359.5 - 26.6, (F, F, 639.5, 359.5))
    np.testing.assert_allclose(ray, np.array([1.0, -0.1, 0.05]) / math.sqrt(1.0125))


def _disc_image(u, v, radius, bgr=(60, 235, 205), background=(120, 110, 100)):
    img = np.zeros((H, W, 3), np.uint8)
    img[:] = background
    yy, xx = np.mgrid[0:H, 0:W]
    img[(xx - u) ** 2 + (yy - v) ** 2 <= radius**2] = bgr
    return img


@pytest.mark.parametrize(("u", "v", "radius"), [(200.3, 100.6, 2.0), (640.0, 360.0, 17.5)])
def test_colour_blobs_are_found_with_their_centroid_whatever_the_size(u, v, radius):
    (blob,) = find_blobs(_disc_image(u, v, radius), ColourConfig())
    assert blob.u == pytest.approx(u, abs=0.3) and blob.v == pytest.approx(v, abs=0.3)
    assert blob.x0 <= u <= blob.x1 and blob.y0 <= v <= blob.y1
    assert blob.area == int(blob.mask.sum())


def test_no_blob_in_an_image_without_ball_colours():
    img = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    img[(hsv[..., 0] >= 15) & (hsv[..., 0] <= 55)] = (128, 128, 128)
    assert find_blobs(img, ColourConfig()) == []


def _frame(img, depth_of, seq=5, stamp=1e9):
    """A frame whose cloud is ``depth_of(u, v)`` along each pixel's ray (NaN: no depth)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([np.ones_like(xx), (639.5 - xx) / F, (359.5 - yy) / F], -1)
    xyz = (rays * depth_of(xx, yy)[..., None]).astype(np.float32)
    return parse_frame(encode_frame(stamp, (F, F, 639.5, 359.5), img, xyz, seq=seq))


def _ball_depth(c, r=0.0335, scene=10.0):
    """Depth (x) of the first surface along each pixel ray: the ball at ``c``, or the scene."""

    def depth(xx, yy):
        d = np.stack([np.ones_like(xx), (639.5 - xx) / F, (359.5 - yy) / F], -1)
        b = d @ c
        dd = (d * d).sum(-1)
        disc = b * b - dd * (c @ c - r * r)
        t = (b - np.sqrt(np.maximum(disc, 0))) / dd
        return np.where(disc >= 0, t, scene)

    return depth


def test_detect_finds_a_rendered_disc_and_the_payload_follows_the_contract():
    c = np.array([3.0, 0.3, -0.2])
    u, v = 639.5 - F * c[1] / c[0], 359.5 - F * c[2] / c[0]
    frame = _frame(_disc_image(u, v, F * 0.0335 / 3.0), _ball_depth(c))
    got = detect(frame, DetectConfig())
    assert isinstance(got, Found) and got.source == "colour"
    assert np.linalg.norm(got.position - c) < 0.005
    det = parse_detection(detection_payload(got, frame.stamp, frame.seq))
    assert isinstance(det, Detection)
    assert det.stamp == frame.stamp and det.seq == 5 and det.frame == "camera"
    ext = CameraExtrinsic(xyz=(0.5, -0.1, 0.3), rpy=(0.0, 0.1, 0.2))
    payload = detection_payload(got, frame.stamp, None, "base", ext.rotation(), ext.translation())
    det = parse_detection(payload)
    assert det.frame == "base" and det.seq is None
    np.testing.assert_allclose(det.position, ext.rotation() @ got.position + ext.xyz)


def test_a_ball_coloured_object_of_the_wrong_size_for_its_depth_is_not_the_ball():
    # a 60 px yellow disc whose depth says 6 m: a ball there would be 6 px across
    frame = _frame(_disc_image(640, 360, 30), lambda xx, yy: np.full_like(xx, 6.0))
    assert detect(frame, DetectConfig()) == Miss("wrong_size")


def test_a_ball_without_depth_is_a_miss_and_no_ball_is_no_ball():
    c = np.array([2.0, 0.0, 0.0])
    img = _disc_image(639.5, 359.5, F * 0.0335 / 2.0)
    assert detect(_frame(img, lambda xx, yy: np.full_like(xx, np.nan)), DetectConfig()) == Miss(
        "no_depth"
    )
    blank = np.full((H, W, 3), 90, np.uint8)
    assert detect(_frame(blank, _ball_depth(c)), DetectConfig()) == Miss("no_ball")


def test_an_external_box_is_used_instead_of_the_colour_filter():
    c = np.array([4.0, -0.5, 0.4])
    u, v = 639.5 - F * c[1] / c[0], 359.5 - F * c[2] / c[0]
    r = F * 0.0335 / 4.0
    grey = np.full((H, W, 3), 90, np.uint8)  # nothing ball-coloured
    frame = _frame(grey, _ball_depth(c))
    box = Box(u - r + 0.5, v - r + 0.5, u + r + 0.5, v + r + 0.5, 0.8, "sports ball")
    got = detect(frame, DetectConfig(), box)
    assert isinstance(got, Found) and got.source == "boxes"
    assert np.linalg.norm(got.position - c) < 0.01
    scene = detect(frame, DetectConfig(), Box(10, 10, 30, 30))  # a box on the scene, 10 m deep
    assert isinstance(scene, Found) and scene.position[0] == pytest.approx(10.0, abs=0.01)
    cfg = DetectConfig(cloud=dataclasses.replace(CLOUD, max_range=8.0))
    assert detect(frame, cfg, Box(10, 10, 30, 30)) == Miss("out_of_range")


def test_detect_never_raises_on_any_valid_frame_layout():
    rng = np.random.default_rng(9)
    cfg = DetectConfig()
    for k in range(300):
        w, h = (int(v) for v in rng.integers(1, 60, 2))
        ch = int(rng.choice([3, 4]))
        img = rng.integers(0, 256, (h, w, ch), dtype=np.uint8)
        if k % 3 == 0:  # ball-coloured pixels somewhere
            img[rng.integers(0, h) :, rng.integers(0, w) :, :3] = (60, 235, 205)
        rw, rh = int(rng.integers(1, w + 1)), int(rng.integers(1, h + 1))
        roi = (int(rng.integers(0, w - rw + 1)), int(rng.integers(0, h - rh + 1)), rw, rh)
        xw, xh = int(rng.integers(1, rw + 1)), int(rng.integers(1, rh + 1))
        xyz = rng.choice([np.nan, np.inf, -np.inf, 0.0, -3.0, 1e30, 2.0, 5.0], (xh, xw, 3))
        dtype = np.float16 if k % 2 else np.float32
        with np.errstate(over="ignore"):
            xyz = (xyz + rng.normal(0, 0.01, xyz.shape)).astype(dtype)
        intr = (float(rng.uniform(1, 2000)), float(rng.uniform(1, 2000)), 0.0, float(h))
        f = parse_frame(encode_frame(1.0, intr, img, xyz, seq=k, xyz_roi=roi))
        assert isinstance(detect(f, cfg), Found | Miss)
        box = Box(*sorted(rng.uniform(-5, w + 5, 2)), *sorted(rng.uniform(-5, h + 5, 2)))
        if box.x1 > box.x0 and box.y1 > box.y0:
            assert isinstance(detect(f, cfg, box), Found | Miss)
