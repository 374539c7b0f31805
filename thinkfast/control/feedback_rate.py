"""Joint velocity measured from ``EgmRobot`` feedback, which carries positions only.

For :mod:`thinkfast.control.core`: how far apart two packets are on the controller's clock,
the velocity two packets measure and whether the arm stands, and the velocity at the newest of
three packets (after a silence in motion). Clock-free: packet times are the controller's.
"""

from __future__ import annotations

import math

import numpy as np

MEASURED_SPAN = 3  # cycles: feedback further apart measures no velocity
REST_SPEED = 1e-3  # rad/s: a measured joint slower than this is at rest


class FeedbackRate:
    """Velocity and rest measured from consecutive feedback packets.

    Args:
        dt: controller cycle [s].

    Attributes:
        fb: ``(controller time [s], q [rad] (6,))`` of the last feedback, None before any.
        rest_since: controller time [s] since which the measured arm is at rest (inf: moving
            or unknown).
        track: ``(s [s], q)`` of the consecutive packets since a silence (for the restart).
    """

    def __init__(self, dt: float):
        self.dt = dt
        self.fb: tuple[float, np.ndarray] | None = None
        self.rest_since = math.inf
        self.track: list[tuple[float, np.ndarray]] = []

    def measure(self, tick, q_meas, earlier=None) -> np.ndarray | None:
        """Measured velocity [rad/s] (6,) from this feedback (``tick``: its
        :class:`~thinkfast.control.egm_clock.ClockTick`) and the one before (``earlier``:
        ``(span [s], q)`` of a superseded packet, else the last one served), or None."""
        q = np.asarray(q_meas, dtype=float)
        last, self.fb = self.fb, (tick.t, q)
        if earlier is not None:
            span, q_prev = earlier
        elif last is not None and not tick.resync:
            span, q_prev = tick.elapsed, last[1]
        else:
            span, q_prev = 0.0, None
        if q_prev is None or not 0.0 < span <= MEASURED_SPAN * self.dt + 1e-9:
            self.rest_since = math.inf
            return None
        qd = (q - q_prev) / span
        if abs(qd).max() < REST_SPEED:  # (np.max's wrapper costs more than the reduction)
            self.rest_since = min(self.rest_since, tick.t - span)
        else:
            self.rest_since = math.inf
        return qd

    def track_velocity(self, tick, q_meas, qd_meas) -> np.ndarray | None:
        """Velocity [rad/s] (6,) at this packet from the packets since the silence, once three
        consecutive ones measure it (exact for a constant acceleration: an arm that the
        controller is slowing down decelerates fast), else None. A pair measures only the
        average over its cycle, up to ``a dt / 2`` off, and the reply acts a cycle later."""
        track = self.track
        if qd_meas is None:  # not consecutive with the one before: start again from this one
            track.clear()
        s = track[-1][0] + tick.elapsed if track else 0.0  # time since the first one [s]
        track.append((s, np.asarray(q_meas, dtype=float)))
        if len(track) < 3:
            return None
        return parabola_velocity(track[-3:])


def span_before(tm_ms, seqno, before, dt: float) -> tuple[float, np.ndarray] | None:
    """``(span [s], q)`` of the packet ``before`` (``(tm_ms, q)`` or ``(tm_ms, q, seqno)``),
    when it was sent at most :data:`MEASURED_SPAN` cycles before this one on the controller's
    clock: counted by seqno where both have one, else by ``tm``."""
    if before is None:
        return None
    if seqno is not None and len(before) > 2 and before[2] is not None:
        ds = (seqno - before[2]) % (1 << 32)
        if not 0 < ds <= MEASURED_SPAN:
            return None
        return ds * dt, np.asarray(before[1], dtype=float)
    if tm_ms is None or before[0] is None:
        return None
    d_ms = (tm_ms - before[0]) % (1 << 32)
    if not 0 < d_ms <= MEASURED_SPAN * 4:
        return None
    return d_ms / 1000.0, np.asarray(before[1], dtype=float)


def parabola_velocity(track) -> np.ndarray | None:
    """Velocity [rad/s] (6,) at the last of three packets ``track`` = ``[(s [s], q [rad] (6,))
    x 3]``: the derivative of the parabola through them (exact for a constant acceleration;
    in differences, so a standing arm measures exactly zero), or None when their times do not
    increase."""
    (s0, q0), (s1, q1), (s2, q2) = track
    h1, h2 = s1 - s0, s2 - s1
    if not (h1 > 0.0 and h2 > 0.0):
        return None
    return (q2 - q1) / h2 * ((2 * h2 + h1) / (h1 + h2)) - (q1 - q0) / h1 * (h2 / (h1 + h2))
