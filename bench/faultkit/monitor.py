"""What the daemon says about itself: its status (20 Hz) and the mode of every setpoint.

Both arrive over zenoh on a session of their own (one that stays up while the detection
publisher's session comes and goes). Kept compact for long runs: the last status in full, a
timeline of a few fields per status, and the setpoint modes as change points only.

Status fields the daemon may publish (used when present, absence tolerated): ``state``,
``throws``, ``braking``, ``safety``, ``interventions``, ``egm``, ``egm_peer``, ``faults``
(``{"deviation", "latched"}``), ``recorder``.
"""

from __future__ import annotations

import json
import threading
import time

import numpy as np

from bench.faultkit import rows as R
from thinkfast.contract import keys


def latched(status: dict) -> bool:
    """A fault is latched: ``faults.latched`` when published, else state ``fault``."""
    faults = status.get("faults")
    if isinstance(faults, dict) and "latched" in faults:
        return bool(faults["latched"])
    return status.get("state") == "fault"


class Monitor:
    """Subscribes to ``<prefix>/status`` and ``<prefix>/setpoints`` on ``session``."""

    def __init__(self, session, prefix: str):
        self.last: dict | None = None
        self.first: dict | None = None
        self.count = 0
        self.timeline: list[tuple[float, str, bool, bool, int]] = []  # t, state, braking, latched,
        self.modes: list[tuple[float, str]] = []  # setpoint mode change points (stamp, mode)
        self.setpoints = 0
        self.lock = threading.Lock()
        session.declare_subscriber(keys.status(prefix), self._on_status)
        session.declare_subscriber(keys.setpoints(prefix), self._on_setpoint)

    def _on_status(self, sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        if not isinstance(msg, dict):
            return
        row = (
            time.time(), str(msg.get("state")), bool(msg.get("braking", False)), latched(msg),
            int(msg.get("throws") or 0),
        )  # fmt: skip
        with self.lock:
            self.first = self.first or msg
            self.last, self.count = msg, self.count + 1
            self.timeline.append(row)

    def _on_setpoint(self, sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
            stamp, mode = float(msg["stamp"]), str(msg["mode"])
        except (ValueError, KeyError, TypeError):
            return
        with self.lock:
            self.setpoints += 1
            if not self.modes or self.modes[-1][1] != mode:
                self.modes.append((stamp, mode))

    # ------------------------------------------------------------------ queries
    def wait_status(self, timeout: float) -> bool:
        deadline = time.time() + timeout
        while self.last is None and time.time() < deadline:
            time.sleep(0.05)
        return self.last is not None

    def state(self) -> str | None:
        return None if self.last is None else self.last.get("state")

    def wait_state(self, states, timeout: float) -> bool:
        """Wait until the status state is one of ``states`` (a string or a tuple)."""
        states = (states,) if isinstance(states, str) else tuple(states)
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.state() in states:
                return True
            time.sleep(0.02)
        return False

    def ever_latched(self, since: float = 0.0) -> bool:
        with self.lock:
            return any(r[3] for r in self.timeline if r[0] >= since)

    def modes_between(self, t0: float, t1: float) -> list[str]:
        """Modes in force between wall times ``t0`` and ``t1`` (setpoints, else status states)."""
        with self.lock:
            points = list(self.modes) or [(r[0], "brake" if r[2] else r[1]) for r in self.timeline]
        out = []
        for i, (t, mode) in enumerate(points):
            t_next = points[i + 1][0] if i + 1 < len(points) else np.inf
            if t <= t1 and t_next >= t0:
                out.append(mode)
        return out

    def first_mode_after(self, modes, t0: float) -> float:
        """Wall time of the first setpoint at or after ``t0`` in one of ``modes`` (nan: none)."""
        with self.lock:
            points = list(self.modes)
        return next((t for t, m in points if t >= t0 and m in modes), float("nan"))

    def braking(self, rows: np.ndarray) -> np.ndarray:
        """Per row: the daemon was braking when the applied reply left (the mode of the last
        setpoint stamped before its arrival; the send time for a cycle without a reply)."""
        t = np.where(np.isnan(rows[:, R.T_ARR]), rows[:, R.T_SEND], rows[:, R.T_ARR])
        with self.lock:
            points = list(self.modes) or [(r[0], "brake" if r[2] else r[1]) for r in self.timeline]
        if not points:
            return np.zeros(len(rows), dtype=bool)
        stamps = np.array([p[0] for p in points])
        brake = np.array([p[1] == "brake" for p in points])
        i = np.searchsorted(stamps, t, side="right") - 1
        return (i >= 0) & brake[np.maximum(i, 0)]

    def egm(self) -> dict:
        """The last status's ``egm`` counters (empty when absent)."""
        return dict((self.last or {}).get("egm") or {})
