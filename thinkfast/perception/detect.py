"""One frame -> one ball detection (or the reason there is none), and its zenoh payload.

Pure: composes :mod:`~thinkfast.perception.colour` (or an external box) and
:mod:`~thinkfast.perception.cloud`. A colour blob must also look like the ball at the depth the
cloud gives (its diameter within ``cloud.size_ratio`` of ``2 r f / x``): a large ball-coloured
object far away, or a speck near the camera, is not the ball. External boxes are trusted.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.contract.detection import encode_detection
from thinkfast.perception.boxes import Box
from thinkfast.perception.cloud import Centre, box_points, centre, centre_ray, shrink_box
from thinkfast.perception.colour import find_blobs
from thinkfast.perception.config import DetectConfig
from thinkfast.perception.frame import Frame

MISS_REASONS = ("no_ball", "no_depth", "out_of_range", "wrong_size")


class Found(NamedTuple):
    """A detected ball.

    Attributes:
        position: ball centre in ``camera`` [m], shape (3,).
        confidence: in [0, 1].
        box: detector box (x0, y0, x1, y1) [px], before shrinking.
        shrunk: the box the cloud was read in [px].
        source: ``"colour"`` or ``"boxes"``.
        n_valid: finite XYZ pixels in the shrunk box.
        spread: robust std of their range [m].
    """

    position: np.ndarray
    confidence: float
    box: tuple[float, float, float, float]
    shrunk: tuple[float, float, float, float]
    source: str
    n_valid: int
    spread: float


class Miss(NamedTuple):
    """No detection in a frame: ``reason`` in :data:`MISS_REASONS`."""

    reason: str


def locate(
    frame: Frame,
    box: tuple[float, float, float, float],
    uv: tuple[float, float],
    cfg: DetectConfig,
    mask: np.ndarray | None = None,
):
    """Shrunk box and :class:`~thinkfast.perception.cloud.Centre` (or a miss reason) of a ball
    whose image centre is ``uv`` [px] and whose box is ``box`` [px]; ``mask`` (bool, the box's
    size) keeps only the ball's own pixels (colour blobs: at long range the box's corners are
    a good part of a small box, and the scene behind may be anywhere)."""
    shrunk = shrink_box(box, (frame.width, frame.height), cfg.shrink)
    origin = (int(box[0]), int(box[1]))
    pts = box_points(frame.xyz, frame.xyz_roi, shrunk, frame.xyz_scale, mask, origin)
    ray = centre_ray(uv[0], uv[1], (frame.fx, frame.fy, frame.cx, frame.cy))
    return shrunk, centre(pts, ray, frame.fx, cfg.cloud)


def size_ok(area: int, depth: float, fx: float, cfg: DetectConfig) -> bool:
    """Whether a blob of ``area`` [px] has the ball's size at ``depth`` [m] (focal ``fx`` [px])."""
    expected = 2.0 * cfg.cloud.ball_radius * fx / depth
    seen = math.sqrt(4.0 * area / math.pi)
    lo, hi = cfg.cloud.size_ratio
    return lo * expected <= seen <= hi * expected


def detect(frame: Frame, cfg: DetectConfig, box: Box | None = None) -> Found | Miss:
    """Detect the ball in ``frame``: in ``box`` if given, else with the colour filter.

    The centre lies on the viewing ray of the blob's centroid (or of the box centre), at the
    distance the point cloud in the shrunk box gives (:func:`~thinkfast.perception.cloud.centre`).

    Colour blobs are tried largest first; the first one with depth and the ball's size wins.
    The miss reason is the first blob's (``"no_ball"`` if there is none).
    """
    if box is not None:
        xyxy = (box.x0, box.y0, box.x1, box.y1)
        uv = (0.5 * (box.x0 + box.x1) - 0.5, 0.5 * (box.y0 + box.y1) - 0.5)
        shrunk, c = locate(frame, xyxy, uv, cfg)
        if isinstance(c, str):
            return Miss(c)
        return _found(c, xyxy, shrunk, "boxes")
    first = None
    for blob in find_blobs(frame.image, cfg.colour):
        xyxy = (float(blob.x0), float(blob.y0), float(blob.x1), float(blob.y1))
        shrunk, c = locate(frame, xyxy, (blob.u, blob.v), cfg, blob.mask)
        if isinstance(c, Centre) and not size_ok(blob.area, c.position[0], frame.fx, cfg):
            c = "wrong_size"
        if isinstance(c, Centre):
            return _found(c, xyxy, shrunk, "colour")
        first = first or c
    return Miss(first or "no_ball")


def _found(c: Centre, box, shrunk, source: str) -> Found:
    return Found(c.position, c.confidence, box, shrunk, source, c.n_valid, c.spread)


def detection_payload(
    found: Found,
    stamp: float,
    seq: int | None,
    frame: str = "camera",
    R_base_camera: np.ndarray | None = None,
    p_base_camera: np.ndarray | None = None,
    camera: str | None = None,
) -> bytes:
    """The contract's detection (docs/INTERFACES.md, "Detections") as UTF-8 JSON.

    Args:
        found: the detection (position in ``camera``).
        stamp: the frame's capture stamp [s].
        seq: the frame's counter, or None (then the key is left out).
        frame: ``"camera"``, or ``"base"`` with the extrinsic ``R_base_camera`` (3, 3) and
            ``p_base_camera`` [m] (3,).
        camera: id of the camera (docs/CAMERAS.md), or None (the default camera: key left out).
    """
    pos = found.position
    if frame == "base":
        pos = R_base_camera @ pos + p_base_camera
    conf = round(float(found.confidence), 4)
    return encode_detection(stamp, pos, frame, conf, seq, camera=camera)
