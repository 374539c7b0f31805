"""The detection message (``<prefix>/detections``): encode one, and validate one JSON payload.

The contract is docs/INTERFACES.md ("Detections") and docs/schemas/detection.schema.json; the
simulated camera and ``thinkfast-detect`` write it with :func:`encode_detection`, the daemon
reads it with :func:`parse_detection`.
:func:`parse_detection` never raises on any input: it returns a :class:`Detection` or a
:class:`Rejection` whose ``reason`` is one of :data:`REJECT_REASONS`. Choices where the
contract is silent:

* an optional key whose value is JSON ``null`` counts as absent;
* keys the contract does not name are ignored (the contract may grow optional fields);
* JSON ``true``/``false`` are never numbers; ``NaN``/``Infinity`` literals parse but are rejected
  by the field check, so they count against that field;
* ``seq`` is an integer in [0, 2**63) (it must fit an int64 column); ``stamp`` a finite number
  >= 0 (plausibility against the receiver's clock is the intake's job);
* ``position`` components beyond ``DetectionLimits.max_abs_position`` are rejected: no camera
  sees a ball that far, and such values would only poison the filter;
* ``camera`` (which camera measured it, docs/CAMERAS.md) is 1-64 characters of letters, digits,
  ``_``, ``.`` and ``-``; absent means the default camera (the run config's ``[camera]``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from typing import Any, NamedTuple

import numpy as np

from thinkfast.config import spec

# the last two are the intake's and the executor's (docs/CAMERAS.md), not the parser's
REJECT_REASONS = (
    "not_bytes", "too_large", "not_utf8", "not_json", "not_object", "missing_stamp", "bad_stamp",
    "missing_position", "bad_position", "bad_frame", "bad_confidence", "bad_seq", "bad_covariance",
    "bad_camera", "unknown_camera", "inconsistent_camera",
)  # fmt: skip
CAMERA_ID = re.compile(r"[A-Za-z0-9_.-]{1,64}")  # a camera id: 1-64 letters, digits, _ . -
FRAMES = ("camera", "base")


@dataclasses.dataclass(frozen=True)
class DetectionLimits:
    """Acceptance limits for detection payloads."""

    max_bytes: int = spec(4096, doc="largest payload accepted", unit="byte", lo=64)
    max_abs_position: float = spec(
        100.0, doc="largest |coordinate| accepted for position", unit="m", lo=0.0, lo_open=True
    )
    max_abs_covariance: float = spec(
        1e4, doc="largest |entry| accepted in covariance", unit="m^2", lo=0.0, lo_open=True
    )
    covariance_tol: float = spec(
        1e-9, doc="relative tolerance for covariance symmetry and PSD checks", lo=0.0
    )
    max_age: float = spec(
        1.0, doc="older stamps (vs the receiver's clock) are stale", unit="s", lo=0.0, lo_open=True
    )
    max_future: float = spec(
        0.01,
        unit="s",
        lo=0.0,
        doc="stamps later than the receive time by more than this are refused (counted future). "
        "A capture stamp precedes its receipt by the pipeline latency (ZED host stamps too, "
        "however late after exposure), so with synchronised clocks only the clock offset "
        "(PTP < 1 ms, LAN NTP a few ms) can put one ahead; an accepted stamp is the order "
        "watermark, so this also bounds how far ahead of the clock the watermark can run "
        "(half a frame period at 50 Hz: at most one extra frame lost)",
    )


class Detection(NamedTuple):
    """One accepted detection.

    Attributes:
        stamp: capture time [s since the Unix epoch].
        position: ball centre [m], shape (3,), read-only, in ``frame``.
        frame: ``"camera"`` or ``"base"``.
        confidence: detector confidence in [0, 1], or None if not sent.
        seq: sender's sequence number, or None.
        covariance: position covariance [m^2], shape (3, 3), read-only, in ``frame``, or None.
        camera: id of the camera that measured it, or None (the default camera).
    """

    stamp: float
    position: np.ndarray
    frame: str = "camera"
    confidence: float | None = None
    seq: int | None = None
    covariance: np.ndarray | None = None
    camera: str | None = None


class Rejection(NamedTuple):
    """A refused payload: ``reason`` is one of :data:`REJECT_REASONS`, ``detail`` for logs."""

    reason: str
    detail: str = ""


def finite_number(v: Any) -> float | None:
    """A finite float from a JSON number (never a bool), else None."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    try:
        f = float(v)
    except OverflowError:  # an int too large for a float
        return None
    return f if math.isfinite(f) else None


def _numbers(v: Any, n: int) -> list[float] | None:
    if not isinstance(v, list) or len(v) != n:
        return None
    out = [finite_number(x) for x in v]
    return None if any(x is None for x in out) else out


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _covariance(v: Any, tol: float, max_abs: float) -> np.ndarray | None:
    vals = _numbers(v, 9)
    if vals is None:
        return None
    c = np.array(vals).reshape(3, 3)
    scale = float(np.abs(c).max())
    if scale > max_abs:
        return None
    scale = max(scale, 1e-300)
    if np.abs(c - c.T).max() > tol * scale or (np.diag(c) < 0).any():
        return None
    if np.linalg.eigvalsh(0.5 * (c + c.T)).min() < -tol * scale:
        return None
    return _frozen(c)


def parse_detection(
    payload: Any, limits: DetectionLimits = DetectionLimits()
) -> Detection | Rejection:
    """Validate one zenoh detection payload.

    Args:
        payload: the sample's bytes (``bytes``, ``bytearray`` or ``memoryview``).
        limits: acceptance limits.

    Returns:
        A :class:`Detection`, or a :class:`Rejection` naming the first problem found. Never raises.
    """
    if not isinstance(payload, bytes | bytearray | memoryview):
        return Rejection("not_bytes", type(payload).__name__)
    if len(payload) > limits.max_bytes:
        return Rejection("too_large", f"{len(payload)} bytes > {limits.max_bytes}")
    try:
        text = bytes(payload).decode("utf-8")
    except UnicodeDecodeError:
        return Rejection("not_utf8")
    try:
        obj = json.loads(text)
    except Exception as exc:  # JSONDecodeError, RecursionError, int digit limits ...
        return Rejection("not_json", type(exc).__name__)
    if not isinstance(obj, dict):
        return Rejection("not_object", type(obj).__name__)
    if obj.get("stamp") is None:
        return Rejection("missing_stamp")
    stamp = finite_number(obj["stamp"])
    if stamp is None or stamp < 0.0:
        return Rejection("bad_stamp", repr(obj["stamp"])[:80])
    if obj.get("position") is None:
        return Rejection("missing_position")
    pos = _numbers(obj["position"], 3)
    if pos is None or max(abs(x) for x in pos) > limits.max_abs_position:
        return Rejection("bad_position", repr(obj["position"])[:80])
    frame = obj.get("frame")
    if frame is None:
        frame = "camera"
    elif frame not in FRAMES:  # a non-string is never equal to a frame name
        return Rejection("bad_frame", repr(frame)[:80])
    conf = obj.get("confidence")
    if conf is not None:
        conf = finite_number(conf)
        if conf is None or not 0.0 <= conf <= 1.0:
            return Rejection("bad_confidence", repr(obj["confidence"])[:80])
    seq = obj.get("seq")
    if seq is not None and (
        isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq < 2**63
    ):
        return Rejection("bad_seq", repr(seq)[:80])
    cov = obj.get("covariance")
    if cov is not None:
        cov = _covariance(cov, limits.covariance_tol, limits.max_abs_covariance)
        if cov is None:
            return Rejection("bad_covariance", repr(obj["covariance"])[:80])
    camera = obj.get("camera")
    if camera is not None and not (isinstance(camera, str) and CAMERA_ID.fullmatch(camera)):
        return Rejection("bad_camera", repr(camera)[:80])
    return Detection(stamp, _frozen(np.array(pos)), frame, conf, seq, cov, camera)


class DetectionCounters:
    """Counts of accepted payloads and of rejections by reason (every reason present, from 0)."""

    def __init__(self) -> None:
        self.accepted = 0
        self.rejected = dict.fromkeys(REJECT_REASONS, 0)

    def count(self, result: Detection | Rejection) -> None:
        """Add one :func:`parse_detection` outcome."""
        if isinstance(result, Rejection):
            self.rejected[result.reason] += 1
        else:
            self.accepted += 1

    @property
    def total(self) -> int:
        """All payloads counted."""
        return self.accepted + sum(self.rejected.values())

    def as_dict(self) -> dict[str, Any]:
        """Plain data for status messages and logs."""
        return {"accepted": self.accepted, "rejected": dict(self.rejected)}


def encode_detection(
    stamp: float,
    position,
    frame: str = "camera",
    confidence: float | None = None,
    seq: int | None = None,
    covariance=None,
    camera: str | None = None,
) -> bytes:
    """One detection message as UTF-8 JSON: ``stamp`` [s since the Unix epoch], ball centre
    ``position`` [m] (3,) in ``frame`` (``camera`` or ``base``); the optional keys are left out
    when None (``covariance``: (3, 3) [m^2] in ``frame``, sent row major; ``camera``: the id of
    the camera that measured it)."""
    obj: dict[str, Any] = {
        "stamp": float(stamp),
        "position": [float(x) for x in position],
        "frame": frame,
    }
    if confidence is not None:
        obj["confidence"] = float(confidence)
    if seq is not None:
        obj["seq"] = int(seq)
    if covariance is not None:
        obj["covariance"] = [float(x) for x in np.asarray(covariance).ravel()]
    if camera is not None:
        obj["camera"] = str(camera)
    return json.dumps(obj).encode("utf-8")
