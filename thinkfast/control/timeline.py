"""The segment timeline: the commanded motion of joints 1-3 of one robot.

The segment in progress (:class:`~thinkfast.control.segments.Segment`), the compiled child edge
queued to start at the end of the edge in progress (``pending``, the tree planner's branches)
and the tree node the motion last reached (``node``). Planners command motion by replacing the
segment; the executor moves it home, holds it and plans it again after a resync. Clock-free:
every time is an argument (the plans' clock) [s].
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.config import ExecutionConfig
from thinkfast.control.segments import HOLD, RETURN, STEER, hold, move
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import Steering

ARM_HOME = 1e-6  # rad, rad/s: the commanded way home has ended (Ruckig lands within 1e-8)


class Timeline:
    """Commanded joint 1-3 motion: the segment in progress and what follows it.

    Args:
        robot: the robot (limits, home).
        cfg: the ``[execution]`` table (``return_speed_scale``: the limits of the way home).

    Attributes:
        steer: Ruckig at the robot's full limits.
        steer_home: Ruckig at the return limits (``return_speed_scale`` of the full ones).
        segment: the segment in progress (commanded from its ``t0``).
        pending: (child node, time it starts) of a compiled edge queued after the edge in
            progress, or None.
        node: the tree node the motion last reached or left (0: home).
    """

    def __init__(self, robot: Robot, cfg: ExecutionConfig):
        self.home = np.array(robot.home[:3], dtype=float)
        self.steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
        scale = cfg.return_speed_scale
        self.steer_home = Steering(
            robot.v_max[:3] * scale, robot.a_max[:3] * scale, robot.j_max[:3] * scale
        )
        self.segment = hold(np.r_[self.home, np.zeros(6)], -np.inf)
        self.pending: tuple[int, float] | None = None
        self.node = 0

    def state(self, t: float) -> np.ndarray:
        """Commanded state (9,) at ``t`` [s]: positions [rad], velocities, accelerations."""
        return self.segment.state(t)

    def at_home(self, t: float) -> bool:
        """The commanded joints 1-3 are home and at rest at ``t`` (within :data:`ARM_HOME`)."""
        s = self.segment.state(t)
        return bool(
            np.all(np.abs(s[:3] - self.home) < ARM_HOME) and np.all(np.abs(s[3:]) < ARM_HOME)
        )

    def steer_to(self, target: np.ndarray, ref: int, t: float) -> None:
        """Move to rest at ``target`` (3,) [rad] (goal ``ref``) from the commanded state at ``t``;
        the segment in progress stays when Ruckig fails."""
        seg = move(self.steer, STEER, self.segment.state(t), target, t, ref)
        if seg is not None:
            self.segment = seg
            self.pending = None

    def start_return(self, t: float, brake: bool = True) -> None:
        """Home within the return limits from the commanded state at ``t``; with ``brake``, the
        full limits when those cannot plan it (it moves faster than they brake); a hold when
        nothing plans."""
        state = self.segment.state(t)
        seg = move(self.steer_home, RETURN, state, self.home, t)
        if seg is None and brake:  # moving faster than the return limits: the full ones
            seg = move(self.steer, RETURN, state, self.home, t)
        self.segment = seg if seg is not None else hold(state, t)

    def hold_at(self, q: np.ndarray, t: float) -> None:
        """Hold joints 1-3 at ``q`` (3,) [rad] at rest from ``t``."""
        self.segment = hold(np.r_[q, np.zeros(6)], t)

    def replan(self, state: np.ndarray, kind: str, target: np.ndarray, ref: int, t: float):
        """The motion of ``kind`` to ``target`` (3,) planned again from ``state`` (9,) at ``t``
        (a resync): a hold at rest stays one; a way home uses the return limits (the full ones
        when those cannot plan it); when Ruckig fails, it comes to rest where ``state`` stops."""
        self.pending = None
        if kind == HOLD and not state[3:].any():
            self.segment = hold(state, t)
            return
        steer = self.steer_home if kind == RETURN else self.steer
        new = move(steer, kind, state, target, t, ref)
        if new is None and steer is not self.steer:
            new = move(self.steer, kind, state, target, t, ref)
        if new is None:  # Ruckig failed: come to rest where the state would stop
            new = move(self.steer, HOLD, state, state[:3], t) or hold(state, t)
        self.segment = new

    def drop(self) -> None:
        """Forget the throw's tree position: no queued edge, back at the root."""
        self.pending = None
        self.node = 0
