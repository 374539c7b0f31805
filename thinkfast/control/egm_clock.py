"""The controller's clock: which controller cycle each ``EgmRobot`` belongs to.

A setpoint is a function of the controller's time, never of how many packets arrived: a
duplicated or stale packet gets the same setpoint again, a missed cycle advances the plan by two
cycles, and after a silence the stream restarts from the measured feedback. Pure: the daemon
passes the header time and its own receive time in.

Three sources, in this order: the header's ``seqno`` (+1 per controller cycle: the clock the
servo moves on), else its ``tm`` [ms], else the receive time snapped to the cycle grid (its
phase following the receive times at most ``max_slew`` per cycle). Times are returned in the
daemon's time base (wall clock seconds, like detection stamps), re-anchored whenever nothing is
moving.

Why seqno comes first, and the anchoring: docs/DESIGN.md, "The control core", "The
controller's clock".
"""

from __future__ import annotations

import math
from typing import NamedTuple

REANCHOR = 0.0005  # s: the time base moves (at rest) when arrivals drifted further than this
STALE = 64  # packets: a seqno at most this far back is a stale packet, further back a restart
_WRAP = 1 << 32
_HALF = 1 << 31


class ClockTick(NamedTuple):
    """Where one ``EgmRobot`` stands on the controller's clock.

    Attributes:
        t: the controller time of this packet in the daemon's time base [s].
        elapsed: controller time since the last served packet [s]; 0 for the same cycle again.
        resync: the stream starts afresh here (first packet, a silence longer than
            ``resync_after``, or a clock that jumped back): restart from the measured feedback.
        repeat: the packet belongs to a cycle already answered (duplicate or stale): answer
            with the same setpoint again.
    """

    t: float
    elapsed: float
    resync: bool
    repeat: bool


class ControllerClock:
    """Maps ``EgmRobot`` packets to controller time (see the module doc).

    Args:
        dt: controller cycle [s] (0.004).
        resync_after: a silence longer than this [s] restarts the stream from the feedback.
        max_slew: largest relative change of a cycle's length when following receive times
            (only without ``tm``).
        anchor_window: arrivals within this long [s] are used to re-anchor the time base.
    """

    def __init__(
        self, dt: float, resync_after: float, max_slew: float = 1e-4, anchor_window: float = 1.0
    ):
        self.dt, self.resync_after, self.max_slew = dt, resync_after, max_slew
        self.anchor_window = anchor_window
        self.t = -math.inf  # controller time of the last served packet (daemon time base)
        self.tm: int | None = None  # its header stamp [ms]
        self.seq: int | None = None  # its sequence number
        self._best: tuple[float, float] = (math.inf, -math.inf)  # (lag [s], when) of the earliest

    def tick(
        self, tm_ms: int | None, now: float, at_rest: bool = False, seqno: int | None = None
    ) -> ClockTick:
        """Place one packet with header stamp ``tm_ms`` (None: absent) and sequence number
        ``seqno`` (None: not used) received at ``now`` [s].

        ``at_rest``: nothing moves (the setpoint does not depend on time), so the time base may
        be re-anchored here.
        """
        if seqno is not None and self.seq is not None and math.isfinite(self.t):
            placed = self._by_seqno(tm_ms, seqno, now, at_rest)
            if placed is not None:
                return placed
        if tm_ms is None:
            self.seq = seqno
            return self._by_arrival(now)
        if self.tm is None or not math.isfinite(self.t):
            return self._restart(tm_ms, now, seqno)
        d_ms = (tm_ms - self.tm + _HALF) % _WRAP - _HALF  # signed, across the uint32 wrap
        elapsed = d_ms / 1000.0
        if elapsed > self.resync_after or elapsed < -self.resync_after:
            return self._restart(
                tm_ms, now, seqno
            )  # a silence, or the controller's clock restarted
        if d_ms <= 0:
            return ClockTick(self.t, 0.0, False, True)
        self.seq = seqno
        return self._advance(tm_ms, elapsed, now, at_rest)

    def _by_seqno(self, tm_ms, seqno: int, now: float, at_rest: bool) -> ClockTick | None:
        """Whole cycles counted by ``seqno``; None: the seqno does not count (use ``tm``)."""
        ds = (seqno - self.seq + _HALF) % _WRAP - _HALF
        d_ms = (
            None if tm_ms is None or self.tm is None else (tm_ms - self.tm + _HALF) % _WRAP - _HALF
        )
        if ds == 0:  # a duplicate, unless the stamp moved on (a seqno that does not count)
            return None if d_ms is not None and d_ms > 0 else ClockTick(self.t, 0.0, False, True)
        if ds < 0:  # a stale packet (its stamp no later), else seqno restarted: place by tm
            stale = ds >= -STALE and (d_ms is None or d_ms <= 0)
            return ClockTick(self.t, 0.0, False, True) if stale else None
        elapsed = ds * self.dt
        if elapsed > self.resync_after:
            return self._restart(tm_ms, now, seqno)  # a silence: cycles ran without answers
        self.seq = seqno
        return self._advance(tm_ms, elapsed, now, at_rest)

    def _advance(self, tm_ms, elapsed: float, now: float, at_rest: bool) -> ClockTick:
        self.tm = tm_ms
        self.t += elapsed
        self._track(now)
        lag = self._best[0]
        if at_rest and abs(lag) > REANCHOR:  # nothing moves: line the time base up with arrivals
            self.t += lag
            self._best = (0.0, self._best[1])
        return ClockTick(self.t, elapsed, False, False)

    def _restart(self, tm_ms: int | None, now: float, seqno: int | None = None) -> ClockTick:
        self.tm, self.t, self.seq = tm_ms, now, seqno
        self._best = (0.0, now)
        return ClockTick(now, 0.0, True, False)

    def _track(self, now: float) -> None:
        """Keep the earliest arrival (smallest lag behind the controller time) seen within the
        anchor window."""
        lag = now - self.t
        best, when = self._best
        if lag <= best or now - when > self.anchor_window:
            self._best = (lag, now)

    def _by_arrival(self, now: float) -> ClockTick:
        self.tm = None
        self._best = (0.0, now)
        since = now - self.t
        if not math.isfinite(self.t) or since > self.resync_after or since < -self.resync_after:
            self.t = now
            return ClockTick(now, 0.0, True, False)
        if since < 0.5 * self.dt:
            return ClockTick(self.t, 0.0, False, True)
        n = max(1, round(since / self.dt))
        nominal = n * self.dt
        slew = self.max_slew * nominal
        elapsed = nominal + min(max(since - nominal, -slew), slew)
        self.t += elapsed
        return ClockTick(self.t, elapsed, False, False)
