"""Motion primitives on joints 1-3: jerk-limited minimum-time Ruckig steering, state to state.

Only state-to-state calls (no intermediate waypoints). Community Ruckig ignores position limits,
so callers check them along the sampled primitive (:mod:`thinkfast.compile.pathcheck`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from thinkfast.errors import NoSolutionError

DOFS = 3


class Limits(NamedTuple):
    """Kinematic limits of joints 1-3: velocity [rad/s], acceleration [rad/s^2], jerk [rad/s^3]."""

    v: np.ndarray
    a: np.ndarray
    j: np.ndarray


class Steering:
    """Reusable Ruckig solver for joints 1-3 (one per process; not thread-safe)."""

    def __init__(self, limits: Limits):
        self.limits = limits
        self._otg = Ruckig(DOFS)
        self._inp = InputParameter(DOFS)
        self._inp.max_velocity = [float(x) for x in limits.v]
        self._inp.max_acceleration = [float(x) for x in limits.a]
        self._inp.max_jerk = [float(x) for x in limits.j]

    def steer(self, state: np.ndarray, target: np.ndarray) -> Trajectory:
        """Minimum-time trajectory from ``state`` (9,) = p, v, a to rest at ``target`` p (3,).

        Raises:
            NoSolutionError: Ruckig reports an error or a non-finite duration.
        """
        inp = self._inp
        inp.current_position = [float(x) for x in state[0:3]]
        inp.current_velocity = [float(x) for x in state[3:6]]
        inp.current_acceleration = [float(x) for x in state[6:9]]
        inp.target_position = [float(x) for x in target]
        inp.target_velocity = [0.0] * DOFS
        inp.target_acceleration = [0.0] * DOFS
        traj = Trajectory(DOFS)
        result = self._otg.calculate(inp, traj)
        if result not in (Result.Working, Result.Finished) or not np.isfinite(traj.duration):
            raise NoSolutionError(f"Ruckig cannot steer to {list(target)}: {result}")
        return traj


def state_at(traj: Trajectory, t: float) -> np.ndarray:
    """State (9,) = p [rad], v [rad/s], a [rad/s^2] of joints 1-3 at time ``t`` [s]."""
    p, v, a = traj.at_time(float(t))
    return np.array([*p, *v, *a])


def positions(traj: Trajectory, times: np.ndarray) -> np.ndarray:
    """Joint 1-3 positions [rad] (N, 3) at ``times`` [s] (N,)."""
    return np.array([traj.at_time(float(t))[0] for t in times])


def position_range(traj: Trajectory, t_end: float, samples: np.ndarray) -> tuple[np.ndarray, ...]:
    """Exact min and max positions (3,) over [0, t_end] from samples and Ruckig's extrema."""
    lo, hi = samples.min(axis=0), samples.max(axis=0)
    for k, ext in enumerate(traj.position_extrema):
        if ext.t_min <= t_end:
            lo[k] = min(lo[k], ext.min)
        if ext.t_max <= t_end:
            hi[k] = max(hi[k], ext.max)
    return lo, hi
