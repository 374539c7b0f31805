"""Commanded motion: joint 1-3 segments (tree edges, terminal edges, steering, return home) and the
wrist tracker for joints 4-6. Time comes in as an argument (wall-clock seconds).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from ruckig import Trajectory

from thinkfast.control.safety_brake import stop_trajectory
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import Steering
from thinkfast.robot.wrist import CoplanarWrist

EDGE, TERMINAL, STEER, RETURN, HOLD = "edge", "terminal", "steer", "return", "hold"


class Segment(NamedTuple):
    """One piece of joint 1-3 motion, commanded from wall time ``t0`` [s].

    Attributes:
        kind: EDGE, TERMINAL, STEER, RETURN or HOLD.
        t0: wall time at which the trajectory's time 0 is commanded [s].
        traj: Ruckig trajectory (None for HOLD).
        end: state (3n,) held after the trajectory (p [rad], v, a of its n joints).
        duration: how long the segment runs before the next decision [s] (eps for tree edges).
        ref: tree node (EDGE), terminal edge (TERMINAL) or goal (STEER) index; -1 otherwise.
    """

    kind: str
    t0: float
    traj: Trajectory | None
    end: np.ndarray
    duration: float
    ref: int = -1

    @property
    def t_end(self) -> float:
        return self.t0 + self.duration

    def state(self, t: float) -> np.ndarray:
        """Commanded state (3n,) at wall time ``t`` (held after the end)."""
        if self.traj is None:
            return self.end
        s = min(max(t - self.t0, 0.0), self.duration, self.traj.duration)
        p, v, a = self.traj.at_time(s)
        return np.array([*p, *v, *a])


def move(steer: Steering, kind: str, state, target, t0: float, ref: int = -1) -> Segment | None:
    """A full move to rest at ``target`` (n,) from ``state`` (3n,) as a Segment commanded from
    ``t0`` (None when Ruckig fails)."""
    traj = steer.to_rest(state, target)
    if traj is None:
        return None
    end = np.r_[np.asarray(target, dtype=float), np.zeros(2 * steer.n)]
    return Segment(kind, t0, traj, end, traj.duration, ref)


def stop(steer: Steering, kind: str, state, t0: float) -> Segment | None:
    """The time-optimal stop from ``state`` (3n,) within ``steer``'s limits, every joint at rest
    at the same time wherever that is, as a Segment commanded from ``t0`` (None when Ruckig
    fails)."""
    n = steer.n
    state = np.asarray(state, dtype=float)
    limits = (steer.v_max, steer.a_max, steer.j_max)
    traj = stop_trajectory(state[:n], state[n : 2 * n], state[2 * n :], limits, sync=True)
    if traj is None:
        return None
    end = np.r_[np.asarray(traj.at_time(traj.duration)[0], dtype=float), np.zeros(2 * n)]
    return Segment(kind, t0, traj, end, traj.duration)


def hold(state: np.ndarray, t0: float) -> Segment:
    """Stay at rest at the position of ``state`` (3n,)."""
    n = len(state) // 3
    end = np.r_[state[:n], np.zeros(2 * n)]
    return Segment(HOLD, t0, None, end, np.inf)


class WristTracker:
    """Joints 4-6: turn the shield towards the incoming ball, jerk-limited, within the limits.

    The shield normal is +x (coplanar with the plane) unless the ball's velocity is known well;
    then it points against the ball's velocity, tilted at most ``max_tilt`` from +x. The wrist
    angles for that normal come from the closed-form x-y-x wrist (:class:`CoplanarWrist`) at the
    commanded joints 1-3; every tick a minimum-time Ruckig move towards them is sampled one tick
    ahead, so the wrist follows with bounded velocity, acceleration and jerk. A tick that starts
    at rest on the goal of the same inputs as the last one (the arm standing still) reuses that
    tick's result: the solve and Ruckig would give it again, bit for bit. ``n``: the wrist's
    joints, ``q[robot.n_arm:]`` (``robot.n_joints - robot.n_arm``).
    """

    def __init__(self, robot: Robot, max_tilt: float, margin: float):
        k = robot.n_arm  # the wrist is q[k:]
        self.n = robot.n_joints - k
        self.rule = CoplanarWrist(robot)
        self.steer = Steering(robot.v_max[k:], robot.a_max[k:], robot.j_max[k:])
        self.lo = robot.q_lower[k:] + margin
        self.hi = robot.q_upper[k:] - margin
        self.max_tilt = max_tilt
        self.state = np.r_[robot.home[k:], np.zeros(2 * self.n)]  # p, v, a of joints 4-6
        self.goal = robot.home[k:].copy()
        self.t = -np.inf
        self._traj, self._t0 = None, 0.0
        self._rest: tuple | None = None  # (inputs, state, goal, traj) of the last standstill

    def reset(self, q: np.ndarray, t: float, qd=None, qdd=None) -> None:
        """Start at wrist angles ``q`` (n,) [rad] with velocity ``qd`` and acceleration ``qdd``
        (n,) (default: at rest) at time ``t`` [s]."""
        z = np.zeros(self.n)
        self.state = np.r_[q, z if qd is None else qd, z if qdd is None else qdd].astype(float)
        self.goal = np.array(q, dtype=float)
        self.t = t
        self._traj, self._t0 = None, t
        self._rest = None

    def memo(self) -> tuple:
        """The tracker's state, to :meth:`recall` (a step replaces its arrays, never writes
        into them: references suffice)."""
        return self.state, self.goal, self.t, self._traj, self._t0, self._rest

    def recall(self, memo: tuple) -> None:
        """Back to the state of :meth:`memo`: as if the steps since had not been made."""
        self.state, self.goal, self.t, self._traj, self._t0, self._rest = memo

    def normal_for(self, ball_velocity: np.ndarray | None) -> np.ndarray:
        """Shield normal (3,) facing a ball moving with ``ball_velocity`` (None: +x, read-only)."""
        x = _PLUS_X
        if ball_velocity is None or not np.all(np.isfinite(ball_velocity)):
            return x
        speed = np.linalg.norm(ball_velocity)
        if speed < 1e-6 or ball_velocity[0] >= 0.0:
            return x
        n = -ball_velocity / speed
        angle = np.arccos(np.clip(n[0], -1.0, 1.0))
        if angle > self.max_tilt:  # rotate back towards +x in the plane of (x, n)
            side = n - n[0] * x
            side /= np.linalg.norm(side)
            n = np.cos(self.max_tilt) * x + np.sin(self.max_tilt) * side
        return n

    def target(self, q123: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Wrist angles (n,) for ``normal`` at joints 1-3 ``q123``, nearest the current wrist."""
        w = self.rule.solve_one(q123, self.state[: self.n], normal)
        return np.clip(w, self.lo, self.hi)

    def step(
        self, t: float, q123: np.ndarray, normal: np.ndarray, goal: np.ndarray | None = None
    ) -> np.ndarray:
        """Advance to wall time ``t``; returns the wrist state (3n,) = p, v, a.

        ``goal``: wrist angles (n,) to go to instead of the ones for ``normal`` (e.g. home on
        the way back, which must not end on the equivalent wrist branch).
        """
        dt = t - self.t
        self.t = t
        if not dt > 0.0 or dt > 0.1:
            return self.state
        inputs = _bits(q123) + _bits(normal) + (b"" if goal is None else _bits(goal))
        rest = self._rest
        if rest is not None and rest[0] == inputs and rest[1] is self.state:
            _, _, self.goal, self._traj = rest  # same inputs, same state: same empty move
            self._t0 = t - dt
            return self.state
        start = self.state
        goal = self.target(q123, normal) if goal is None else np.clip(goal, self.lo, self.hi)
        traj = self.steer.to_rest(start, goal)
        if traj is not None:
            self.goal, self._traj, self._t0 = goal, traj, t - dt
        elif self._traj is None:  # nothing to follow: stay (already at rest when no traj yet)
            return self.state
        s = min(t - self._t0, self._traj.duration)  # else: go on along the last valid move
        p, v, a = self._traj.at_time(s)
        state = np.array([*p, *v, *a])
        if traj is not None and traj.duration == 0.0 and state.tobytes() == start.tobytes():
            self._rest = (inputs, start, goal, traj)  # a standstill: keep the same state object
            return start
        self.state = state
        return self.state


_PLUS_X = np.array([1.0, 0.0, 0.0])
_PLUS_X.setflags(write=False)


def _bits(a) -> bytes:
    """The exact float64 bits of ``a`` (tells -0.0 from 0.0; NaN equals its own bits)."""
    return np.asarray(a, dtype=np.float64).tobytes()
