"""The planner process's executor, kept in step with the reply process's (``--reply-process``).

The reply loop follows the published plan and replans from what it commanded (a resync, a
start, a fault held, a recovery); each such call reaches the planner process as a row, and
:class:`PlannerSide` makes it on the planner's executor too, then steps that executor at every
reply's controller time (so queued tree edges start, throws end and the arm returns home).
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.executor import Executor


class PlannerSide:
    """The planner's executor driven by the reply loop's rows (module doc)."""

    def __init__(self, executor: Executor):
        self._ex = executor

    def call(self, name: str, t: float, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        """Make the reply loop's call ``name`` (:data:`thinkfast.control.plan.CALLS`) at ``t``
        [s] from the commanded state ``q, qd, qdd`` (n_joints,). Raises what the executor
        raises."""
        ex = self._ex
        if name == "resync":
            ex.resync(q, qd, qdd, t)
        elif name == "start_from":
            ex.start_from(q, t)
        elif name == "hold_fault":
            ex.hold_fault(q, t)
        else:
            ex.recover(q, t)

    def step(self, t: float, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        """Step the executor at the reply's controller time ``t`` [s], its wrist put where the
        reply loop's is (``q, qd, qdd`` (n_joints,), commanded). Raises what it raises."""
        ex = self._ex
        n = ex.n_arm  # the wrist's joints follow the positioning joints
        ex.wrist.reset(q[n:], t, qd[n:], qdd[n:])
        ex.setpoint(t)
