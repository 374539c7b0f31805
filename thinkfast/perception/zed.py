"""ZED SDK output -> the fields of a camera frame message (pure: no SDK, no zenoh, no clock).

The bridge (:mod:`thinkfast.perception.zed_bridge`) opens the camera with the SDK's own image
conventions, ``COORDINATE_SYSTEM.IMAGE`` (x right, y down, z forward) in ``UNIT.MILLIMETER``,
and this module turns what it retrieves into docs/CAMERA_FRAMES.md's message: the ``camera``
frame (REP-103: x forward, y left, z up, origin at the left optical centre) in metres, the left
image without its alpha channel, the stamp in seconds since the Unix epoch. The payload itself
is built by :func:`thinkfast.perception.frame.frame_buffer`, the one encoder of the message.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.contract.camera_mode import ZED_MODES
from thinkfast.perception.frame import frame_buffer

SDK_UNITS = {"MILLIMETER": 1e-3, "CENTIMETER": 1e-2, "METER": 1.0}  # sl.UNIT -> metres


class ZedFrame(NamedTuple):
    """One frame's message fields.

    Attributes:
        stamp: capture time [s since the Unix epoch].
        seq: frame counter.
        intrinsics: (fx, fy, cx, cy) of the rectified left image [px].
        image: left image, shape (H, W, 3), uint8, BGR (a view of the SDK's BGRA image).
        xyz: point cloud in ``camera`` [m], shape (h, w, 3), float32; non-finite without depth.
        xyz_roi: (x, y, w, h) of the left image the XYZ image covers [px].
    """

    stamp: float
    seq: int
    intrinsics: tuple[float, float, float, float]
    image: np.ndarray
    xyz: np.ndarray
    xyz_roi: tuple[int, int, int, int]


def xyz_step(mode: str, step: int) -> int:
    """The XYZ subsampling: ``step``, or for 0 the recommended one (2 at HD720, 1 at VGA)."""
    if step:
        return step
    return 2 if ZED_MODES[mode].image_size[0] >= 1280 else 1


def image_to_camera(xyz: np.ndarray, unit_scale: float, step: int = 1) -> np.ndarray:
    """The SDK's point cloud in the ``camera`` frame, in metres, at 1/``step`` resolution.

    Args:
        xyz: ``MEASURE.XYZ`` in ``COORDINATE_SYSTEM.IMAGE`` (x right, y down, z forward),
            shape (H, W, 3 or 4), in SDK units; NaN / ±inf where there is no depth.
        unit_scale: metres per SDK unit (``UNIT.MILLIMETER``: 1e-3).
        step: keep every ``step``-th row and column (cell (i, j) covers image rows
            ``i step .. (i + 1) step``), cropping the image to a multiple of ``step``.

    Returns:
        (H // step, W // step, 3) float32: x forward = z, y left = -x, z up = -y, in metres.
        Non-finite samples stay non-finite.
    """
    h, w = xyz.shape[0] // step, xyz.shape[1] // step
    src = xyz[: h * step : step, : w * step : step]
    out = np.empty((h, w, 3), np.float32)
    np.multiply(src[..., 2], unit_scale, out=out[..., 0])
    np.multiply(src[..., 0], -unit_scale, out=out[..., 1])
    np.multiply(src[..., 1], -unit_scale, out=out[..., 2])
    return out


def zed_frame(
    image: np.ndarray,
    xyz: np.ndarray,
    stamp_ns: int,
    intrinsics: tuple[float, float, float, float],
    seq: int,
    unit_scale: float = 1e-3,
    step: int = 1,
    stamp_lag: float = 0.0,
) -> ZedFrame:
    """The message fields of one grabbed frame.

    Args:
        image: ``VIEW.LEFT``, shape (H, W, 4) BGRA (or (H, W, 3) BGR) uint8.
        xyz: ``MEASURE.XYZ`` as :func:`image_to_camera` takes it, at the image's resolution.
        stamp_ns: ``get_timestamp(TIME_REFERENCE.IMAGE).get_nanoseconds()`` [ns since the epoch].
        intrinsics: (fx, fy, cx, cy) of the rectified left camera [px].
        seq: frame counter.
        unit_scale: metres per SDK unit.
        step: XYZ subsampling.
        stamp_lag: reception minus capture time [s], subtracted from the stamp.

    Raises:
        ValueError: image and point cloud of different sizes, or not 3/4 channels.
    """
    if image.ndim != 3 or image.shape[2] not in (3, 4) or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3|4) uint8, got {image.shape} {image.dtype}")
    if xyz.ndim != 3 or xyz.shape[:2] != image.shape[:2] or xyz.shape[2] not in (3, 4):
        raise ValueError(f"point cloud {xyz.shape} does not match the image {image.shape}")
    cloud = image_to_camera(xyz, unit_scale, step)
    roi = (0, 0, cloud.shape[1] * step, cloud.shape[0] * step)
    stamp = int(stamp_ns) * 1e-9 - stamp_lag
    k = tuple(float(v) for v in intrinsics)
    return ZedFrame(stamp, seq, k, image[..., :3], cloud, roi)  # type: ignore[arg-type]


def frame_payload(f: ZedFrame, xyz_dtype: str = "float16") -> bytearray:
    """``f`` as a docs/CAMERA_FRAMES.md payload (``bgr8``, XYZ in metres as ``xyz_dtype``)."""
    h, w = f.image.shape[:2]
    xyz_size = (f.xyz.shape[1], f.xyz.shape[0])
    fb = frame_buffer(f.stamp, f.intrinsics, (w, h), f.seq, "bgr8", xyz_dtype, 3, xyz_size,
                      f.xyz_roi)  # fmt: skip
    fb.image[...] = f.image
    fb.xyz[...] = f.xyz
    return fb.payload
