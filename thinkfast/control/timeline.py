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
from thinkfast.control.safety_limits import REL_TOL
from thinkfast.control.segments import HOLD, RETURN, STEER, Segment, hold, move, stop
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import Steering, peaks

ARM_HOME = 1e-6  # rad, rad/s: the commanded way home has ended (Ruckig lands within 1e-8)


class Timeline:
    """Commanded motion of the positioning joints (``robot.n_arm``, joints 1-3): the segment in
    progress and what follows it.

    Args:
        robot: the robot (limits, home).
        cfg: the ``[execution]`` table (``return_speed_scale``: the limits of the way home).

    Attributes:
        n_arm: the joints it commands (``robot.n_arm``); a state is (3 n_arm,): p, v, a.
        steer: Ruckig at the robot's full limits.
        steer_home: Ruckig at the return limits (``return_speed_scale`` of the full ones).
        home_steers: the ways home tried in turn (:meth:`home_move`): the return limits, the
            same with the full jerk, the full limits.
        segment: the segment in progress (commanded from its ``t0``).
        pending: (child node, time it starts) of a compiled edge queued after the edge in
            progress, or None.
        node: the tree node the motion last reached or left (0: home).
    """

    def __init__(self, robot: Robot, cfg: ExecutionConfig):
        n = self.n_arm = robot.n_arm
        self.home = np.array(robot.home[:n], dtype=float)
        v_max, a_max, j_max = robot.v_max[:n], robot.a_max[:n], robot.j_max[:n]
        self.steer = Steering(v_max, a_max, j_max)
        scale = cfg.return_speed_scale
        self.steer_home = Steering(v_max * scale, a_max * scale, j_max * scale)
        # with the full jerk, a brake from a fast state passes no full limit (home_move)
        full_jerk = Steering(v_max * scale, a_max * scale, j_max)
        self.home_steers = (self.steer_home, full_jerk, self.steer)
        self.segment = hold(np.r_[self.home, np.zeros(2 * n)], -np.inf)
        self.pending: tuple[int, float] | None = None
        self.node = 0

    def state(self, t: float) -> np.ndarray:
        """Commanded state (3 n_arm,) at ``t`` [s]: positions [rad], velocities, accelerations."""
        return self.segment.state(t)

    def at_home(self, t: float) -> bool:
        """The commanded joints 1-3 are home and at rest at ``t`` (within :data:`ARM_HOME`)."""
        s, n = self.segment.state(t), self.n_arm
        return bool(
            np.all(np.abs(s[:n] - self.home) < ARM_HOME) and np.all(np.abs(s[n:]) < ARM_HOME)
        )

    def steer_segment(self, target: np.ndarray, ref: int, t: float) -> Segment | None:
        """The move to rest at ``target`` (n_arm,) [rad] (goal ``ref``) from the commanded state
        at ``t``, or None when Ruckig fails (pure: the timeline is not changed)."""
        return move(self.steer, STEER, self.segment.state(t), target, t, ref)

    def start_return(self, t: float) -> None:
        """Home from the commanded state at ``t`` (:meth:`home_move`); a hold when nothing
        plans."""
        state = self.segment.state(t)
        seg = self.home_move(state, t)
        self.segment = seg if seg is not None else hold(state, t)

    def stop_then_home(self, t: float) -> None:
        """Stop at the full limits from the commanded state at ``t`` (a retracted throw); the
        stop is the first piece of the way home (kind RETURN): once it ends away from home, the
        executor plans the rest (:meth:`start_return`). Home at once when it is nothing to stop
        or Ruckig fails it."""
        state = self.segment.state(t)
        seg = stop(self.steer, RETURN, state, t) if state[self.n_arm :].any() else None
        if seg is None:
            self.start_return(t)
            return
        self.segment = seg

    def home_move(self, state: np.ndarray, t: float, ok=None) -> Segment | None:
        """The move home from the commanded ``state`` (3 n_arm,) at ``t`` [s] with the first of
        :attr:`home_steers` whose move stays within the full velocity and acceleration limits
        and passes ``ok(traj)`` (when given); else the full limits' move (the last of them), or
        None when Ruckig fails it or ``ok`` refuses it.

        From a state faster than the return limits allow, Ruckig first brakes it with the jerk
        it is given: a speed still rising while its acceleration ramps down at the return
        limits' lower jerk rises further than the full limits' plan it left would have, past
        the full velocity limit where that plan was close to it (the supervisor would clamp
        it). With the full jerk it rises no further than that plan's own."""
        tol = 1.0 + REL_TOL  # as the supervisor judges: a plan exactly at a limit passes
        v_max, a_max = self.steer.v_max * tol, self.steer.a_max * tol
        for steer in self.home_steers:
            seg = move(steer, RETURN, state, self.home, t)
            if seg is None or (ok is not None and not ok(seg.traj)):
                continue
            if steer is self.steer:
                return seg
            v_peak, a_peak = peaks(seg.traj)
            if np.all(v_peak <= v_max) and np.all(a_peak <= a_max):
                return seg
        return None

    def hold_at(self, q: np.ndarray, t: float) -> None:
        """Hold joints 1-3 at ``q`` (n_arm,) [rad] at rest from ``t``."""
        self.segment = hold(np.r_[q, np.zeros(2 * self.n_arm)], t)

    def replan(self, state: np.ndarray, kind: str, target: np.ndarray, ref: int, t: float):
        """The motion of ``kind`` to ``target`` (n_arm,) planned again from ``state`` (3 n_arm,)
        at ``t`` (a resync): a hold at rest stays one; a way home is :meth:`home_move` (it
        always ends at home); when Ruckig fails, it comes to rest where ``state`` stops."""
        self.pending = None
        if kind == HOLD and not state[self.n_arm :].any():
            self.segment = hold(state, t)
            return
        if kind == RETURN:
            new = self.home_move(state, t)
        else:
            new = move(self.steer, kind, state, target, t, ref)
        if new is None:  # Ruckig failed: come to rest where the state would stop
            new = move(self.steer, HOLD, state, state[: self.n_arm], t) or hold(state, t)
        self.segment = new

    def drop(self) -> None:
        """Forget the throw's tree position: no queued edge, back at the root."""
        self.pending = None
        self.node = 0
