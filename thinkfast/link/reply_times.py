"""Reply timing of a real-time server, in fixed ring buffers (no allocation per reply).

Kept by :class:`~thinkfast.link.egm_server.EgmServer` (``timing=True``) and summarised in the
daemon's status message, so a running daemon shows what its EGM replies cost.
"""

from __future__ import annotations

import numpy as np


class ReplyTimes:
    """Timing of the replies, kept in fixed ring buffers (no allocation per reply).

    Args:
        size: how many recent replies the percentiles of :meth:`summary` cover.

    Attributes:
        wait_s: kernel arrival -> read by the server [s], ring (size,); NaN when the socket has
            no arrival time stamps. Includes the wake-up and any work in progress when it came.
        work_s: read -> reply ready to send [s], ring (size,): decode, ``reply_fn``, encode.
            (Not ``sendto`` itself: on loopback it may run the receiver before it returns.)
        count: replies timed since the start.
        max_wait_s, max_work_s: largest since the start [s].
        late: replies that left more than ``late_after`` after their request arrived (wait +
            work; work alone without arrival stamps): they reached the controller after its
            next cycle began, which kept its last reference for that cycle.
        late_after: the controller's cycle [s] (None: nothing is counted late).
    """

    def __init__(self, size: int = 5000, late_after: float | None = None):
        self.wait_s = np.full(size, np.nan)
        self.work_s = np.full(size, np.nan)
        self.count = 0
        self.late, self.late_after = 0, late_after
        self.max_wait_s = 0.0
        self.max_work_s = 0.0

    def add(self, wait_s: float, work_s: float) -> None:
        """Record one reply: ``wait_s`` (NaN if unknown) and ``work_s`` [s]."""
        i = self.count % len(self.work_s)
        self.wait_s[i] = wait_s
        self.work_s[i] = work_s
        self.count += 1
        if work_s > self.max_work_s:
            self.max_work_s = work_s
        if wait_s > self.max_wait_s:  # False for NaN
            self.max_wait_s = wait_s
        if self.late_after is not None:
            self.late += (work_s if wait_s != wait_s else wait_s + work_s) > self.late_after

    def summary(self) -> dict:
        """``{"wait_us": {...}, "work_us": {...}, "n": count, "late": late}``; each has p50, p99,
        max over the recent replies and ``max_all`` since the start [us] (None where nothing was
        measured)."""
        n = min(self.count, len(self.work_s))
        out: dict = {"n": self.count, "late": self.late}
        for name, ring, top in (
            ("wait_us", self.wait_s, self.max_wait_s),
            ("work_us", self.work_s, self.max_work_s),
        ):
            x = ring[:n][~np.isnan(ring[:n])]
            if not len(x):
                out[name] = None
                continue
            p50, p99 = np.percentile(x, [50, 99])
            out[name] = {
                "p50": round(1e6 * float(p50), 1),
                "p99": round(1e6 * float(p99), 1),
                "max": round(1e6 * float(x.max()), 1),
                "max_all": round(1e6 * top, 1),
            }
        return out
