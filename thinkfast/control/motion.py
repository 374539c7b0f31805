"""What the control core drives: the motion source behind its replies.

Two things meet it: the daemon's :class:`~thinkfast.control.executor.Executor` (throw episodes,
planners, the wrist) and the reply process's :class:`~thinkfast.control.plan.PlanFollower` (the
planner process's plan, followed). The core asks for the setpoint at a controller time and
tells the source where the commanded arm really is after a silence, a supervisor's change, a
fault or a recovery; positions [rad], velocities [rad/s], accelerations [rad/s^2], (n_joints,).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Motion(Protocol):
    """The core's motion source (module doc).

    Attributes:
        mode: the executor mode it is in (:mod:`thinkfast.control.modes`).
        away: held away from home, until told to go home.
    """

    mode: str
    away: bool

    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity to command at controller time ``t`` [s]."""
        ...

    def retract(self) -> None:
        """Forget the last setpoint asked for (it was prepared ahead and will not be sent)."""
        ...

    def resync(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, t: float) -> None:
        """Go on from the commanded state at ``t`` with the same intent."""
        ...

    def start_from(self, q: np.ndarray, t: float) -> None:
        """Begin at the measured joints at rest."""
        ...

    def hold_fault(self, q: np.ndarray, t: float) -> None:
        """Latched fault: hold ``q`` at rest until restarted."""
        ...

    def recover(self, q: np.ndarray, t: float) -> None:
        """After a stop at ``q``: drop the throw and return home."""
        ...
