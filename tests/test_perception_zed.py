"""The ZED conversion (thinkfast/perception/zed.py) on the stand-in SDK's synthetic frames:
IMAGE coordinates in millimetres become the ``camera`` frame in metres, the stamp seconds, the
payload the one frame encoder's, read back by the detector's own decoder."""

import numpy as np
import pytest
import zed_standin as sl

from thinkfast.perception.frame import Frame, parse_frame
from thinkfast.perception.zed import frame_payload, image_to_camera, xyz_step, zed_frame

RES = sl.RESOLUTION.VGA
W, H = sl.SIZES[RES]
F = sl.FOCAL[RES]
CX, CY = (W - 1) / 2.0, (H - 1) / 2.0


def test_point_cloud_becomes_camera_frame_in_metres_and_projects_back_to_its_pixel():
    xyz = sl.xyz_mm(RES, 3)
    cam = image_to_camera(xyz, 1e-3)
    assert cam.shape == (H, W, 3) and cam.dtype == np.float32
    finite = np.isfinite(xyz[..., :3]).all(-1)
    assert np.array_equal(np.isfinite(cam).all(-1), finite)  # holes stay holes
    z = sl.depth_mm(3) * 1e-3
    assert np.allclose(cam[..., 0][finite], z)  # depth is x (forward), in metres
    # the detector's ray of pixel (u, v) is (1, (cx - u) / f, (cy - v) / f): y left, z up
    v, u = np.nonzero(finite)
    p = cam[v, u]
    assert np.allclose(CX - F * p[:, 1] / p[:, 0], u, atol=1e-3)
    assert np.allclose(CY - F * p[:, 2] / p[:, 0], v, atol=1e-3)
    left_of_centre = cam[H // 2, 10]
    assert left_of_centre[1] > 0.0 and abs(left_of_centre[2]) < 0.01


def test_subsampled_cloud_takes_every_step_th_pixel_of_the_cropped_image():
    xyz = sl.xyz_mm(sl.RESOLUTION.HD720, 1)
    cam = image_to_camera(xyz, 1e-3, 2)
    assert cam.shape == (360, 640, 3)
    full = image_to_camera(xyz, 1e-3)
    assert np.array_equal(cam, full[::2, ::2], equal_nan=True)
    odd = image_to_camera(xyz[:, :1279], 1e-3, 2)  # an odd width is cropped, not padded
    assert odd.shape == (360, 639, 3)


def test_frame_fields_stamp_in_seconds_minus_the_lag_image_without_alpha():
    ns = sl.stamp_ns(5, 100)
    f = zed_frame(sl.image(RES, 5), sl.xyz_mm(RES, 5), ns, (F, F, CX, CY), 5, 1e-3, 1, 0.03)
    assert f.stamp == pytest.approx(ns * 1e-9 - 0.03, abs=1e-6)
    assert f.seq == 5 and f.intrinsics == (F, F, CX, CY) and f.xyz_roi == (0, 0, W, H)
    assert f.image.shape == (H, W, 3)
    assert np.array_equal(f.image, sl.image(RES, 5)[..., :3])


def test_mismatched_image_and_cloud_are_refused():
    with pytest.raises(ValueError, match="does not match"):
        zed_frame(sl.image(RES, 1), sl.xyz_mm(sl.RESOLUTION.HD720, 1), 0, (F, F, CX, CY), 1)
    with pytest.raises(ValueError, match="uint8"):
        zed_frame(sl.xyz_mm(RES, 1), sl.xyz_mm(RES, 1), 0, (F, F, CX, CY), 1)


@pytest.mark.parametrize("dtype, step", [("float16", 2), ("float32", 1)])
def test_payload_is_read_back_by_the_detectors_decoder(dtype, step):
    res = sl.RESOLUTION.HD720
    w, h = sl.SIZES[res]
    k = (532.0, 532.0, (w - 1) / 2.0, (h - 1) / 2.0)
    ns = sl.stamp_ns(2, 60)
    f = zed_frame(sl.image(res, 2), sl.xyz_mm(res, 2), ns, k, 2, 1e-3, step)
    got = parse_frame(frame_payload(f, dtype))
    assert isinstance(got, Frame), got
    assert got.stamp == pytest.approx(ns * 1e-9, abs=1e-6) and got.seq == 2
    assert (got.width, got.height, got.fx, got.fy, got.cx, got.cy) == (w, h, *k)
    assert got.image.shape == (h, w, 3)
    assert np.array_equal(got.image, sl.image(res, 2)[..., :3])
    assert got.xyz.dtype == np.dtype(dtype) and got.xyz_scale == 1.0
    assert got.xyz.shape == (h // step, w // step, 3) and got.xyz_roi == (0, 0, w, h)
    want = image_to_camera(sl.xyz_mm(res, 2), 1e-3, step)
    assert np.allclose(got.xyz.astype(np.float32), want, rtol=1e-3, equal_nan=True)


def test_recommended_step_is_two_at_hd720_one_at_vga_unless_set():
    assert xyz_step("HD720", 0) == 2 and xyz_step("VGA", 0) == 1 and xyz_step("VGA", 3) == 3
