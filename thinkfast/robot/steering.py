"""Minimum-time jerk-limited moves to rest (Ruckig), state to state: the one Ruckig wrapper.

The compiler grows tree edges and the runtime plans moves (and re-solves compiled edges) with the
same solver and the same inputs, so a runtime edge is the compiled edge (tests/test_steering.py).
Failure contract: :meth:`Steering.to_rest` returns None when Ruckig fails or raises (online, a
failure must cost a hold, never an exception); :meth:`Steering.steer` raises
:class:`~thinkfast.errors.NoSolutionError` instead (offline, where a failure is a bug).

Only state-to-state calls (no intermediate waypoints). Community Ruckig ignores position limits:
callers check them along the sampled motion (:mod:`thinkfast.compile.pathcheck`, the safety
supervisor online).
"""

from __future__ import annotations

import math

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from thinkfast.errors import NoSolutionError

_OK = (Result.Working, Result.Finished)


class Steering:
    """Reusable Ruckig solver for ``n`` joints (one per user; not thread-safe).

    Args:
        v_max, a_max, j_max: velocity [rad/s], acceleration [rad/s^2] and jerk [rad/s^3]
            limits, shape (n,).
    """

    def __init__(self, v_max, a_max, j_max):
        n = len(v_max)
        self.n = n
        self.v_max, self.a_max, self.j_max = (
            np.array(x, dtype=float) for x in (v_max, a_max, j_max)
        )
        self._otg = Ruckig(n)
        self._inp = InputParameter(n)
        self._inp.max_velocity = _floats(self.v_max)
        self._inp.max_acceleration = _floats(self.a_max)
        self._inp.max_jerk = _floats(self.j_max)
        self._inp.target_velocity = [0.0] * n  # every move ends at rest
        self._inp.target_acceleration = [0.0] * n

    @classmethod
    def for_robot(cls, robot, scale: float = 1.0, joints: int = 3) -> Steering:
        """Joints ``1..joints`` of ``robot`` with its limits scaled by ``scale``."""
        return cls(
            *(np.asarray(x[:joints]) * scale for x in (robot.v_max, robot.a_max, robot.j_max))
        )

    def to_rest(self, state: np.ndarray, target: np.ndarray) -> Trajectory | None:
        """Trajectory from ``state`` (3n,) = p, v, a to rest at ``target`` (n,); None on failure."""
        self._set_state(state)
        return self._solve(target)

    def to_rest_each(self, state: np.ndarray, targets) -> list[Trajectory | None]:
        """:meth:`to_rest` from one ``state`` (3n,) to each of ``targets`` (K, n) in turn."""
        self._set_state(state)
        return [self._solve(target) for target in targets]

    def _set_state(self, state) -> None:
        n, inp = self.n, self._inp
        state = _floats(state)
        inp.current_position = state[:n]
        inp.current_velocity = state[n : 2 * n]
        inp.current_acceleration = state[2 * n : 3 * n]

    def _solve(self, target) -> Trajectory | None:
        inp = self._inp
        inp.target_position = _floats(target)
        traj = Trajectory(self.n)
        try:
            result = self._otg.calculate(inp, traj)
        except Exception:  # ruckig.RuckigError: invalid input or a numerically hard case
            return None
        if result not in _OK or not math.isfinite(traj.duration):
            return None
        return traj

    def steer(self, state: np.ndarray, target: np.ndarray) -> Trajectory:
        """:meth:`to_rest`, raising where a failure is a bug.

        Raises:
            NoSolutionError: Ruckig reports an error or a non-finite duration.
        """
        traj = self.to_rest(state, target)
        if traj is None:
            raise NoSolutionError(f"Ruckig cannot steer from {list(state)} to {list(target)}")
        return traj


def state_at(traj: Trajectory, t: float) -> np.ndarray:
    """State (3n,) = p [rad], v [rad/s], a [rad/s^2] at time ``t`` [s]."""
    p, v, a = traj.at_time(float(t))
    return np.array([*p, *v, *a])


def positions(traj: Trajectory, times: np.ndarray) -> np.ndarray:
    """Positions [rad] (N, n) at ``times`` [s] (N,)."""
    return np.array([traj.at_time(float(t))[0] for t in times])


def position_range(traj: Trajectory, t_end: float, samples: np.ndarray) -> tuple[np.ndarray, ...]:
    """Exact min and max positions (n,) over [0, t_end] from samples and Ruckig's extrema."""
    lo, hi = samples.min(axis=0), samples.max(axis=0)
    for k, ext in enumerate(traj.position_extrema):
        if ext.t_min <= t_end:
            lo[k] = min(lo[k], ext.min)
        if ext.t_max <= t_end:
            hi[k] = max(hi[k], ext.max)
    return lo, hi


def feasible_acceleration(v, a, v_max, a_max, j_max) -> np.ndarray:
    """The acceleration [rad/s^2] (n,) nearest ``a`` that a plan at these limits can hold at
    speed ``v`` [rad/s] (n,), ``|v| <= v_max``: within ``a_max``, and where it drives the speed
    up, no larger than a ramp to zero at ``j_max`` can take off before the speed reaches
    ``v_max`` (``a^2 / (2 j_max) <= v_max - |v|``). Ruckig given a larger one brakes past
    ``v_max``. Limits [rad/s, rad/s^2, rad/s^3] shape (n,)."""
    v, a = np.asarray(v, dtype=float), np.asarray(a, dtype=float)
    a = np.clip(a, -a_max, a_max)
    top = np.sqrt(2.0 * j_max * np.maximum(v_max - np.abs(v), 0.0))
    return np.where(a * np.sign(v) > top, np.sign(v) * top, a)


def peaks(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Exact largest speed [rad/s] and acceleration magnitude [rad/s^2] of each joint, shapes
    (n,), over the whole trajectory (from Ruckig's piecewise-constant-jerk profiles, including
    the brake it prepends when the start state lies outside the limits it was given: that brake
    may pass them, e.g. a speed still rising while the acceleration ramps down at the jerk
    limit)."""
    n = traj.degrees_of_freedom
    v_peak, a_peak = np.zeros(n), np.zeros(n)
    for section in traj.profiles:
        for k, prof in enumerate(section):
            brake = prof.brake
            pieces = [(brake.t[i], brake.v[i], brake.a[i], brake.j[i]) for i in range(2)]
            pieces += [(prof.t[i], prof.v[i], prof.a[i], prof.j[i]) for i in range(7)]
            for dt, v, a, j in pieces:
                if dt <= 0.0:
                    continue
                v1, a1 = v + a * dt + 0.5 * j * dt * dt, a + j * dt
                top = max(abs(v), abs(v1))
                if j != 0.0 and 0.0 < -a / j < dt:  # the speed turns inside the piece
                    top = max(top, abs(v - 0.5 * a * a / j))
                v_peak[k] = max(v_peak[k], top)
                a_peak[k] = max(a_peak[k], abs(a), abs(a1))
    return v_peak, a_peak


def _floats(a) -> list[float]:
    """``a`` as a list of Python floats (``tolist`` when it already is a float64 array)."""
    if isinstance(a, np.ndarray) and a.dtype == np.float64:
        return a.tolist()
    return [float(x) for x in a]
