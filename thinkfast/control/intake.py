"""Detection intake: payload bytes -> validated, ordered detection in ``base``, or a counted drop.

Never raises. Every payload is counted once: accepted, rejected by reason (malformed), or dropped
by order (duplicate, out of order, stale, future).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.contract.detection import (
    DetectionCounters,
    DetectionLimits,
    Rejection,
    parse_detection,
)
from thinkfast.contract.frames import CameraExtrinsic, PlanePose, to_base
from thinkfast.estimate.fusion import DEFAULT_CAMERA

ORDER_CLASSES = ("new", "duplicate", "out_of_order", "stale", "future")


class Accepted(NamedTuple):
    """A detection ready for the filter: capture stamp [s], ball centre [m] (3,) in the plane's
    frame (``base`` when the plane has no pose), the
    sender's seq, and the id of the camera that took it (None: the default camera)."""

    stamp: float
    position: np.ndarray
    seq: int | None
    camera: str | None = None


class Intake:
    """Stateful intake of the detection stream of one or more cameras.

    ``last_stamp`` is the order watermark of the default camera (``watermarks``: one per camera):
    only later stamps of the same camera are new, so one camera's late detection is not dropped
    because another camera's newer one came first (the filter puts it in its place). A watermark
    moves only with an accepted detection, whose stamp is at most ``max_future`` after its
    receive time, so no detection (nor a burst of them) can put it further ahead of the clock
    than that. A detection naming a camera not configured is rejected (``unknown_camera``).

    Args:
        camera: pose of the default camera (``camera`` key absent, or ``base``) in ``base``.
        limits: payload and clock limits.
        cameras: the other cameras (``[[cameras]]`` of the run config).
        plane: the tree's plane: accepted positions are moved from ``base`` into its frame
            (None or a plane without a pose: they stay in ``base``).
    """

    def __init__(
        self,
        camera: CameraExtrinsic,
        limits: DetectionLimits,
        cameras=(),
        plane: PlanePose | None = None,
    ):
        self.plane = PlanePose() if plane is None else plane
        self.R = camera.rotation()
        self.p = camera.translation()
        poses = {c.id: c.extrinsic() for c in cameras}
        self.poses = {k: (e.rotation(), e.translation()) for k, e in poses.items()}
        self.limits = limits
        self.counters = DetectionCounters()
        self.order = {"duplicate": 0, "out_of_order": 0, "stale": 0, "future": 0}
        self.watermarks: dict[str | None, tuple[float, int | None]] = {}
        self.last_stamp: float | None = None
        self.last_seq: int | None = None
        self.last_drop: tuple[str, str] | None = None  # (reason, detail) of the last drop

    def take(self, payload: bytes, now: float | None) -> Accepted | None:
        """Validate one payload received at ``now`` (None: no clock checks, for lockstep runs)."""
        try:
            det = parse_detection(payload, self.limits)
        except Exception:  # parse_detection never raises; a bug there must not stop the daemon
            det = Rejection("not_json", "internal error")
        if isinstance(det, Rejection):
            self.counters.count(det)
            self.last_drop = (det.reason, det.detail)
            return None
        cam = None if det.camera == DEFAULT_CAMERA else det.camera
        if cam is not None and cam not in self.poses:
            det = Rejection("unknown_camera", cam)
            self.counters.count(det)
            self.last_drop = (det.reason, det.detail)
            return None
        last_stamp, last_seq = self.watermarks.get(cam, (None, None))
        cls = classify_order(det.stamp, det.seq, last_stamp, last_seq, now, self.limits)
        if cls != "new":
            self.order[cls] += 1
            self.last_drop = (cls, f"stamp {det.stamp:.3f}")
            return None
        self.counters.count(det)
        self.watermarks[cam] = (det.stamp, det.seq)
        if cam is None:
            self.last_stamp, self.last_seq = det.stamp, det.seq
            base = to_base(det, self.R, self.p)
        else:
            base = to_base(det, *self.poses[cam])
        position = self.plane.to_plane(np.asarray(base.position, dtype=float))
        return Accepted(det.stamp, position, det.seq, cam)

    def reject_accepted(self, reason: str) -> None:
        """Count a detection :meth:`take` accepted as rejected for ``reason`` after all (the
        executor found its camera inconsistent: ``inconsistent_camera``)."""
        self.counters.accepted -= 1
        self.counters.rejected[reason] += 1

    def dropped(self, reason: str) -> int:
        """Payloads dropped so far for ``reason`` (a rejection reason or an order class)."""
        return self.counters.rejected.get(reason, self.order.get(reason, 0))

    def as_dict(self) -> dict:
        """Counts for status messages."""
        return {**self.counters.as_dict(), "dropped": dict(self.order)}


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
