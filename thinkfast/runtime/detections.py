"""Ball detections from zenoh: validate one JSON payload, count outcomes, order, camera -> base.

The payload contract is the project's detection message (README, "Interfaces").
:func:`parse_detection` never raises on any input: it returns a :class:`Detection` or a
:class:`Rejection` whose ``reason`` is one of :data:`REJECT_REASONS`. Choices where the
contract is silent:

* an optional key whose value is JSON ``null`` counts as absent;
* keys the contract does not name are ignored (the contract may grow optional fields);
* JSON ``true``/``false`` are never numbers; ``NaN``/``Infinity`` literals parse but are rejected
  by the field check, so they count against that field;
* ``seq`` is an integer in [0, 2**63) (it must fit an int64 column); ``stamp`` a finite number
  >= 0 (plausibility against the receiver's clock is :func:`classify_order`'s job);
* ``position`` components beyond ``DetectionLimits.max_abs_position`` are rejected: no camera
  sees a ball that far, and such values would only poison the filter.
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any, NamedTuple

import numpy as np

from thinkfast.config import spec

REJECT_REASONS = (
    "not_bytes", "too_large", "not_utf8", "not_json", "not_object", "missing_stamp", "bad_stamp",
    "missing_position", "bad_position", "bad_frame", "bad_confidence", "bad_seq", "bad_covariance",
)  # fmt: skip
ORDER_CLASSES = ("new", "duplicate", "out_of_order", "stale", "future")
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


@dataclasses.dataclass(frozen=True)
class CameraExtrinsic:
    """Pose of the ``camera`` frame in ``base`` (``T_base_camera``).

    Default cell (ASSUMPTION until the cell is measured): the ZED 2i sits at the robot base on
    the camera pedestal of robots/irb1600/robot.toml (box x 0.40..0.52 m, top at z 0.25 m), lens
    at (0.46, 0, 0.30) m, level and looking +x (the same way as the base, towards the thrower).
    ``rpy`` is fixed-axis roll-pitch-yaw as in URDF: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
    """

    xyz: tuple[float, float, float] = spec(
        (0.46, 0.0, 0.30),
        doc="camera origin in base (ASSUMED default cell: lens on the pedestal at the robot base)",
        unit="m",
        length=3,
    )
    rpy: tuple[float, float, float] = spec(
        (0.0, 0.0, 0.0),
        doc="camera orientation in base (roll, pitch, yaw), radians: within one turn, so that "
        "degrees are refused",
        unit="rad",
        length=3,
        lo=-math.tau,
        hi=math.tau,
    )

    def rotation(self) -> np.ndarray:
        """``R_base_camera``, shape (3, 3), read-only."""
        return rotation_from_rpy(self.rpy)

    def translation(self) -> np.ndarray:
        """``p_base_camera`` [m], shape (3,), read-only."""
        p = np.array(self.xyz, dtype=float)
        p.setflags(write=False)
        return p


class Detection(NamedTuple):
    """One accepted detection.

    Attributes:
        stamp: capture time [s since the Unix epoch].
        position: ball centre [m], shape (3,), read-only, in ``frame``.
        frame: ``"camera"`` or ``"base"``.
        confidence: detector confidence in [0, 1], or None if not sent.
        seq: sender's sequence number, or None.
        covariance: position covariance [m^2], shape (3, 3), read-only, in ``frame``, or None.
    """

    stamp: float
    position: np.ndarray
    frame: str = "camera"
    confidence: float | None = None
    seq: int | None = None
    covariance: np.ndarray | None = None


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
    return Detection(stamp, _frozen(np.array(pos)), frame, conf, seq, cov)


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


def classify_order(
    stamp: float,
    seq: int | None,
    last_stamp: float | None,
    last_seq: int | None,
    now: float | None = None,
    limits: DetectionLimits = DetectionLimits(),
) -> str:
    """Place a detection in time: against the receiver's clock, then against the last one used.

    The capture stamp decides (a sender restart may reset ``seq``); ``seq`` only breaks ties.
    Checking against ``now`` keeps a stamp from the future (say now + 0.2 s, or 1e300) from
    becoming the "last" stamp and making every later detection look out of order: an accepted
    stamp is at most ``now + max_future``.

    Args:
        stamp: capture time of the new detection [s].
        seq: its sequence number, or None.
        last_stamp: capture time of the last detection used, or None if there is none.
        last_seq: its sequence number, or None.
        now: receiver's clock [s, same clock as the stamps], or None to skip the age checks
            (lockstep simulation).
        limits: ``max_age`` and ``max_future``.

    Returns:
        One of :data:`ORDER_CLASSES`: ``"stale"`` (older than ``now - max_age``), ``"future"``
        (later than ``now + max_future``), ``"new"`` (later than the last one, or same stamp
        with a larger ``seq``), ``"duplicate"`` (same stamp, and same ``seq`` or a ``seq``
        missing) or ``"out_of_order"`` (older, or same stamp with a smaller ``seq``). Only
        ``"new"`` detections should reach the filter.
    """
    if now is not None:
        if stamp < now - limits.max_age:
            return "stale"
        if stamp > now + limits.max_future:
            return "future"
    if last_stamp is None or stamp > last_stamp:
        return "new"
    if stamp < last_stamp:
        return "out_of_order"
    if seq is None or last_seq is None or seq == last_seq:
        return "duplicate"
    return "new" if seq > last_seq else "out_of_order"


def rotation_from_rpy(rpy) -> np.ndarray:
    """Fixed-axis roll, pitch, yaw [rad] -> rotation matrix ``Rz @ Ry @ Rx``, shape (3, 3)."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    R = np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
    return _frozen(R)


def to_base(det: Detection, R_base_camera: np.ndarray, p_base_camera: np.ndarray) -> Detection:
    """Express a detection in ``base``: ``p_base = R p_cam + t``, ``C_base = R C_cam R^T``.

    Args:
        det: an accepted detection; returned unchanged if already in ``base``.
        R_base_camera: rotation, shape (3, 3) (e.g. :meth:`CameraExtrinsic.rotation`).
        p_base_camera: camera origin in base [m], shape (3,).

    Returns:
        The same detection with ``frame="base"``.
    """
    if det.frame == "base":
        return det
    pos = _frozen(R_base_camera @ det.position + p_base_camera)
    cov = None
    if det.covariance is not None:
        cov = _frozen(R_base_camera @ det.covariance @ R_base_camera.T)
    return det._replace(position=pos, frame="base", covariance=cov)
