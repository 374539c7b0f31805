"""2-D boxes from an external detector (``<prefix>/camera/boxes``), matched to their frames.

Payload: one UTF-8 JSON object per frame the detector ran on (docs/CAMERA_FRAMES.md)::

    {"stamp": 1763800000.1234, "seq": 17,
     "boxes": [{"xyxy": [x0, y0, x1, y1], "score": 0.91, "label": "sports ball"}]}

``stamp`` (required) and ``seq`` (optional) are the frame's; ``xyxy`` are left-image pixel
coordinates (x right, y down, ``x1``/``y1`` exclusive); ``score`` (0..1) and ``label`` are
optional. An empty list says the detector saw no ball in that frame. :func:`parse_boxes` never
raises.
"""

from __future__ import annotations

import json
from typing import Any, NamedTuple

from thinkfast.contract.detection import finite_number

BOX_REJECT_REASONS = (
    "too_large", "not_utf8", "not_json", "not_object", "bad_stamp", "bad_seq", "bad_boxes",
)  # fmt: skip
MAX_BOXES = 256


class Box(NamedTuple):
    """One box: corners [px] (``x1``, ``y1`` exclusive), score in [0, 1] (1 if absent), label."""

    x0: float
    y0: float
    x1: float
    y1: float
    score: float = 1.0
    label: str = ""


class Boxes(NamedTuple):
    """The boxes of one frame, identified by its capture stamp [s] and ``seq`` (or None)."""

    stamp: float
    seq: int | None
    boxes: tuple[Box, ...]


class BoxRejection(NamedTuple):
    """A refused box payload: ``reason`` in :data:`BOX_REJECT_REASONS`."""

    reason: str
    detail: str = ""


def _box(b: Any) -> Box | None:
    if not isinstance(b, dict):
        return None
    xyxy = b.get("xyxy")
    if not isinstance(xyxy, list) or len(xyxy) != 4:
        return None
    c = [finite_number(v) for v in xyxy]
    if any(v is None for v in c) or not (c[2] > c[0] and c[3] > c[1]):
        return None
    score = b.get("score")
    score = 1.0 if score is None else finite_number(score)
    if score is None or not 0.0 <= score <= 1.0:
        return None
    label = b.get("label", "")
    if not isinstance(label, str):
        return None
    return Box(*c, score, label)


def parse_boxes(payload: Any, max_bytes: int = 65536) -> Boxes | BoxRejection:
    """Validate one box payload (bytes); returns :class:`Boxes` or a :class:`BoxRejection`."""
    try:
        if len(payload) > max_bytes:
            return BoxRejection("too_large", f"{len(payload)} bytes")
        text = bytes(payload).decode("utf-8")
    except (TypeError, UnicodeDecodeError):
        return BoxRejection("not_utf8")
    try:
        obj = json.loads(text)
    except Exception as exc:
        return BoxRejection("not_json", type(exc).__name__)
    if not isinstance(obj, dict):
        return BoxRejection("not_object", type(obj).__name__)
    stamp = finite_number(obj.get("stamp"))
    if stamp is None or stamp < 0.0:
        return BoxRejection("bad_stamp", repr(obj.get("stamp"))[:80])
    seq = obj.get("seq")
    if seq is not None and (isinstance(seq, bool) or not isinstance(seq, int) or seq < 0):
        return BoxRejection("bad_seq", repr(seq)[:80])
    raw = obj.get("boxes")
    if not isinstance(raw, list) or len(raw) > MAX_BOXES:
        return BoxRejection("bad_boxes", "expected a list of at most 256 boxes")
    boxes = [_box(b) for b in raw]
    if any(b is None for b in boxes):
        return BoxRejection("bad_boxes", repr(raw)[:80])
    return Boxes(stamp, seq, tuple(boxes))


def same_frame(a_stamp: float, a_seq: int | None, b_stamp: float, b_seq: int | None) -> bool:
    """Whether boxes and a frame belong together: equal ``seq`` if both have one, else stamps
    within 0.1 ms (JSON carries a float stamp exactly; a frame period is 10 ms or more)."""
    if a_seq is not None and b_seq is not None:
        return a_seq == b_seq and abs(a_stamp - b_stamp) < 1.0
    return abs(a_stamp - b_stamp) < 1e-4


def pick_box(boxes: Boxes, min_score: float, label: str = "") -> Box | None:
    """The highest-scoring box with ``score >= min_score`` (and ``label``, if given), or None."""
    ok = [b for b in boxes.boxes if b.score >= min_score and (not label or b.label == label)]
    return max(ok, key=lambda b: b.score, default=None)
