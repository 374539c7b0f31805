"""The move home at start-up, checked against the cell before it is commanded.

When the daemon first hears the controller with the arm away from home, it holds the arm where
it stands. With ``--go-home`` it then checks the exact motion the executor would command home
(the same executor code, from the same state at rest, sampled every EGM cycle) against the robot
and cell collision model of robot.toml, and only a clear path is commanded. The check runs in
slices between EGM replies (:meth:`WayHome.step` with a deadline), so no reply waits for it.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from thinkfast.robot.collision import CollisionChecker

MAX_DURATION = 60.0  # s: a way home longer than this is refused (something is wrong)


class WayHomeResult(NamedTuple):
    """Outcome of a check.

    Attributes:
        clear: no collision along the way.
        duration: length of the motion checked [s].
        samples: configurations checked.
        detail: empty when clear, else what collides and when.
    """

    clear: bool
    duration: float
    samples: int
    detail: str


class WayHome:
    """Checks the way home from ``q0`` (n_joints,) at rest, a slice at a time.

    Args:
        make_executor: builds a fresh executor (the same configuration as the daemon's).
        checker: collision checker of the robot in its cell.
        q0: measured joints [rad] (n_joints,).
        dt: sampling step [s] (one EGM cycle).
    """

    def __init__(self, make_executor, checker: CollisionChecker, q0, dt: float):
        self.checker, self.q0, self.dt = checker, np.array(q0, dtype=float), dt
        self._samples = _way_home(make_executor, self.q0, dt)
        self.result: WayHomeResult | None = None
        self._n = 0
        self._t = 0.0

    def step(self, deadline: float) -> WayHomeResult | None:
        """Check configurations until ``deadline`` (``time.perf_counter()``); the result once
        the whole way is checked (then again on every call), else None."""
        if self.result is not None:
            return self.result
        for t, q in self._samples:
            self._n, self._t = self._n + 1, t
            if self.checker.in_collision(q):
                pairs = ", ".join(f"{a}-{b}" for a, b in self.checker.collisions(q)[:3])
                self.result = WayHomeResult(
                    False, t, self._n, f"{pairs} at t = {t:.2f} s, q = {np.round(q, 3).tolist()}"
                )
                return self.result
            if t > MAX_DURATION:
                self.result = WayHomeResult(False, t, self._n, f"longer than {MAX_DURATION} s")
                return self.result
            if time.perf_counter() >= deadline:
                return None
        self.result = WayHomeResult(True, self._t, self._n, "")
        return self.result

    def run(self) -> WayHomeResult:
        """The whole check at once (tests and tools)."""
        while (r := self.step(float("inf"))) is None:
            pass
        return r


def _way_home(make_executor, q0: np.ndarray, dt: float):
    """Yield ``(t, q)`` along the motion home an executor commands from ``q0`` at rest."""
    from thinkfast.control.executor import IDLE

    ex = make_executor()
    ex.home_on_start = True
    ex.start_from(q0, 0.0)
    t = 0.0
    while True:
        q, _ = ex.setpoint(t)
        yield t, q
        if ex.mode == IDLE:
            return
        t += dt
