"""Host stall probe: a process that sleeps 1 ms at a time and notes every wake-up that came late.

A late wake-up means the host did not run this process when it asked to: the same stalls cost
the daemon and the simulated controller their replies (docs/BENCHMARKS.md: pauses that come
from below the guest's scheduler). Its own process, so it measures the machine, not this
program's GIL. It stops when its stdin closes and prints one JSON line: the stalls (wall-clock
start [s], length [s]) longer than ``--threshold-ms``.

:class:`StallProbe` runs it; :func:`stalls_near` attributes events (missed replies) to stalls.
"""

from __future__ import annotations

import json
import os
import selectors
import subprocess
import sys
import time

import numpy as np

from bench.faultkit import spawn

SLEEP = 0.001


def probe(threshold: float, stdin_fd: int) -> list[tuple[float, float]]:
    """Sleep ``SLEEP`` at a time until ``stdin_fd`` closes; stalls longer than ``threshold`` [s]."""
    sel = selectors.DefaultSelector()
    sel.register(stdin_fd, selectors.EVENT_READ)
    events: list[tuple[float, float]] = []
    last = time.perf_counter()
    while True:
        if sel.select(SLEEP) and not os.read(stdin_fd, 4096):
            break
        now = time.perf_counter()
        late = now - last - SLEEP
        if late > threshold:
            events.append((time.time() - (now - last), late))
        last = now
    return events


class StallProbe:
    """The probe in a child process (see the module doc)."""

    def __init__(self, threshold_ms: float = 2.0):
        self.proc = spawn("probe", str(threshold_ms), stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.t_start = time.time()

    def stop(self) -> np.ndarray:
        """Stop the probe; stalls as an array (N, 2): wall start [s], length [s]."""
        try:
            out, _ = self.proc.communicate(timeout=10)
            events = json.loads(out.decode().strip() or "[]")
        except (subprocess.TimeoutExpired, ValueError):
            self.proc.kill()
            events = []
        return np.array(events, dtype=float).reshape(-1, 2)


def stalls_near(times: np.ndarray, stalls: np.ndarray, before: float, after: float) -> np.ndarray:
    """For each event time [s] (N,): does a stall overlap ``[t - before, t + after]``? (N,) bool."""
    times = np.asarray(times, float)
    if len(stalls) == 0 or len(times) == 0:
        return np.zeros(len(times), dtype=bool)
    start, end = stalls[:, 0], stalls[:, 0] + stalls[:, 1]
    lo, hi = times[:, None] - before, times[:, None] + after
    return ((start[None, :] <= hi) & (end[None, :] >= lo)).any(axis=1)


def attribute(missed_times, missed_own: int, stalls: np.ndarray) -> dict:
    """Missed replies (send times [s]) near a host stall, late sends of the controller itself
    (``missed_own``), and the rest (unexplained); with the stalls' count and longest [ms]."""
    t = np.asarray(missed_times, float)
    n_host = int(stalls_near(t, stalls, 0.006, 0.004).sum())
    own = min(missed_own, len(t) - n_host)
    st = stalls[:, 1] if len(stalls) else np.zeros(0)
    return {
        "missed_host_stall": n_host,
        "missed_unexplained": int(len(t) - n_host - own),
        "host_stalls": int(len(st)),
        "host_stall_max_ms": round(1e3 * float(st.max()), 1) if len(st) else 0.0,
    }


def rss_mb(pid: int) -> float | None:
    """Resident memory of process ``pid`` [MB] (Linux ``/proc``), None when unknown."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        return None
    return None


def main() -> int:
    threshold = float(sys.argv[1]) / 1e3 if len(sys.argv) > 1 else 0.002
    events = probe(threshold, sys.stdin.fileno())
    print(json.dumps([[round(a, 6), round(b, 6)] for a, b in events]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
