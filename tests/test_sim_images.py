"""Synthetic ZED frames: pinhole projection, clean scene, depth noise as the camera model says,
motion blur, holes."""

import dataclasses

import cv2
import numpy as np
import pytest

from thinkfast.perception.colour import colour_mask
from thinkfast.perception.config import ColourConfig
from thinkfast.perception.frame import Frame, parse_frame
from thinkfast.sim.camera import CameraModelConfig, depth_sigma
from thinkfast.sim.images import FrameRenderConfig, FrameRenderer

CAM = CameraModelConfig()
F = CAM.focal_px


@pytest.fixture(scope="module")
def renderer():
    return FrameRenderer(FrameRenderConfig(image_noise=0.0), CAM, seed=3)


def _frame(r, p, v=None, sd=0.0, seed=0, seq=1):
    payload, truth = r.render(1e9 + seq, seq, p, v, sd, np.random.default_rng(seed))
    f = parse_frame(bytes(payload))
    assert isinstance(f, Frame)
    return f, truth


def test_scenes_hold_no_ball_coloured_pixel():
    cfg = FrameRenderConfig()
    band = ColourConfig()
    for seed in range(3):
        r = FrameRenderer(cfg, CAM, seed)
        hsv = cv2.cvtColor(np.ascontiguousarray(r.background), cv2.COLOR_BGR2HSV)
        lo, hi = (np.array(b, np.uint8) for b in cfg.avoid_hsv)
        assert cv2.countNonZero(cv2.inRange(hsv, lo, hi)) == 0
        f, truth = _frame(r, None, seed=seed)  # with sensor noise: still nothing in the band
        assert truth.position is None
        assert cv2.countNonZero(colour_mask(f.image, band)) == 0


def test_the_ball_lands_where_the_pinhole_model_puts_it(renderer):
    p = np.array([3.0, 0.4, -0.25])
    f, truth = _frame(renderer, p)
    assert (f.fx, f.fy, f.cx, f.cy) == (F, F, 639.5, 359.5)
    ball = np.abs(f.image.astype(int) - renderer.background.astype(int)).sum(-1) > 0
    w = np.abs(f.image.astype(float) - renderer.background).sum(-1) * ball
    yy, xx = np.mgrid[0 : f.height, 0 : f.width]
    u, v = (xx * w).sum() / w.sum(), (yy * w).sum() / w.sum()
    assert u == pytest.approx(639.5 - F * p[1] / p[0], abs=0.3)
    assert v == pytest.approx(359.5 - F * p[2] / p[0], abs=0.3)
    diameter = 2 * 0.0335 * F / 3.0
    assert ball.sum() == pytest.approx(np.pi * diameter**2 / 4, rel=0.35)
    np.testing.assert_array_equal(truth.position, p)


def test_noise_free_cloud_points_lie_on_the_ball_or_the_scene(renderer):
    p = np.array([2.0, -0.2, 0.1])
    f, _ = _frame(renderer, p)
    xyz = f.xyz.astype(float)
    on_ball = np.linalg.norm(xyz - p, axis=-1)
    near = np.isfinite(on_ball) & (on_ball < 0.2)
    assert near.sum() > 100
    np.testing.assert_allclose(on_ball[near], 0.0335, atol=1e-4)
    ok = np.isfinite(xyz).all(-1)
    assert 0.9 < ok.mean() < 0.99  # holes: about 5 % of the scene


@pytest.mark.parametrize("depth", [2.0, 6.0])
def test_depth_noise_has_the_camera_model_std_with_the_configured_correlation(depth):
    cfg = FrameRenderConfig(image_noise=0.0, invalid_fraction=0.0, depth_correlation=0.5)
    r = FrameRenderer(cfg, CAM, seed=1)
    p = np.array([depth, 0.0, 0.0])
    clean, _ = _frame(r, p)
    ball = np.linalg.norm(clean.xyz.astype(float) - p, axis=-1) < 0.05  # NaN: False
    errs = []
    for k in range(150):
        f, _ = _frame(r, p, sd=0.2, seed=k)
        errs.append(f.xyz[..., 0][ball] - clean.xyz[..., 0][ball])
    errs = np.array(errs)  # frames x ball pixels, depth error along x
    sigma = depth_sigma(depth, 0.2, CAM)
    assert errs.std() == pytest.approx(sigma, rel=0.12)
    common = errs.mean(axis=1)  # the part shared by the ball's pixels in one frame
    assert common.std() == pytest.approx(np.sqrt(0.5) * sigma, rel=0.2)


def test_motion_blur_follows_the_image_velocity():
    r = FrameRenderer(FrameRenderConfig(image_noise=0.0), CAM, seed=2)
    p = np.array([1.5, 0.0, 0.0])
    v = np.array([0.0, -3.0, 0.0])  # to the right in the image
    still, t0 = _frame(r, p)
    moving, t1 = _frame(r, p, v)
    assert t0.blur_px == 0.0
    assert t1.blur_px == pytest.approx(F * 3.0 * CAM.exposure / 1.5, rel=1e-6)  # 5.3 px

    def extent(f):
        ball = np.abs(f.image.astype(int) - r.background.astype(int)).sum(-1) > 30
        ys, xs = np.nonzero(ball)
        return xs.max() - xs.min(), ys.max() - ys.min()

    (w0, h0), (w1, h1) = extent(still), extent(moving)
    assert w1 - w0 == pytest.approx(t1.blur_px, abs=1.5) and abs(h1 - h0) <= 1


def test_a_ball_out_of_view_renders_the_scene_only(renderer):
    for p in ([0.1, 0.0, 0.0], [2.0, 5.0, 0.0], [25.0, 0.0, 0.0]):
        f, truth = _frame(renderer, np.array(p))
        assert truth.position is None
        np.testing.assert_array_equal(f.image, renderer.background)


def test_the_cloud_can_be_float16_at_half_resolution():
    cfg = dataclasses.replace(FrameRenderConfig(), xyz_dtype="float16", xyz_step=2)
    r = FrameRenderer(cfg, CAM, seed=0)
    payload, _ = r.render(5.0, 9, np.array([4.0, 0, 0]), None, 0.1, np.random.default_rng(0))
    f = parse_frame(bytes(payload))
    assert f.xyz.shape == (360, 640, 3) and f.xyz.dtype == np.float16
    assert f.xyz_roi == (0, 0, 1280, 720)
    assert len(payload) < 4.2e6  # 2.76 MB image + 1.38 MB cloud
