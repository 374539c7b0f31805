"""Positions of many Ruckig trajectories at many times, in numpy, bit for bit ``at_time``.

``Trajectory.at_time`` is one call from Python per sample (its cost: docs/BENCHMARKS.md, "Kernel
figures the code refers to"), and the compiler samples tens of thousands of primitives at
hundreds of times each. A state-to-state trajectory is, per joint, an
optional two-phase brake followed by seven constant-jerk phases; this module reads those phases
once per trajectory (``Trajectory.profiles``) and evaluates Ruckig's own formula,

    p(t) = p0 + t (v0 + t (a0 / 2 + t j / 6)),

with the same phase choice (``upper_bound`` on the cumulative phase times), the same time offsets
and the same floating-point operations in the same order, so every sample equals ``at_time``'s
exactly (tests/test_batch_traj.py holds it on random trajectories with and without brakes).
Only single-section trajectories (no intermediate waypoints), as everywhere in thinkfast.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class TrajectoryTable:
    """The phases of M trajectories of n joints, ready for :meth:`positions`.

    Args:
        trajectories: Ruckig trajectories (one section each), all of the same n joints.
    """

    def __init__(self, trajectories: Sequence):
        m = len(trajectories)
        n = trajectories[0].degrees_of_freedom if m else 0
        self.trajectories = list(trajectories)
        self.n_joints = n
        self.duration = np.empty(m)
        self.t_sum = np.empty((m, n, 7))
        self.jerk = np.zeros((m, n, 8))  # phase 7 (held end) has no jerk
        self.p, self.v, self.a = (np.empty((m, n, 8)) for _ in range(3))
        self.brake = np.zeros((m, n))  # brake duration [s] (0: none)
        self.brake_t = np.zeros((m, n))  # end of the first brake phase [s]
        self.brake_pvaj = np.zeros((4, m, n, 2))
        for k, traj in enumerate(trajectories):
            self.duration[k] = traj.duration
            for d, prof in enumerate(traj.profiles[0]):
                self.t_sum[k, d] = np.cumsum(prof.t)  # partial_sum: sequential, as in Ruckig
                self.jerk[k, d, :7] = prof.j
                self.p[k, d], self.v[k, d], self.a[k, d] = prof.p, prof.v, prof.a
                b = prof.brake
                if b.duration > 0.0:
                    self.brake[k, d] = b.duration
                    self.brake_t[k, d] = b.t[0]
                    self.brake_pvaj[:, k, d] = (b.p, b.v, b.a, b.j)

    def positions(self, owner: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Positions [rad] (S, n): trajectory ``owner[s]`` at ``times[s]`` [s], each (S,)."""
        owner = np.asarray(owner, dtype=np.intp)
        times = np.asarray(times, dtype=np.float64)
        out = np.empty((len(times), self.n_joints))
        rows = np.arange(len(times))
        after = times >= self.duration[owner]
        for d in range(self.n_joints):
            t_sum = self.t_sum[owner, d]  # (S, 7)
            last = t_sum[:, 6]
            brake = self.brake[owner, d]
            t = np.where(brake > 0.0, times - brake, times)  # past the brake (fixed below)
            phase = np.count_nonzero(t_sum <= t[:, None], axis=1)  # upper_bound
            before = t_sum[rows, np.maximum(phase - 1, 0)]
            local = np.where(phase > 0, t - before, t)
            held = t >= last
            phase[held] = 7
            local[held] = (t - last)[held]
            p = _integrate(local, self.p[owner, d, phase], self.v[owner, d, phase],
                           self.a[owner, d, phase], self.jerk[owner, d, phase])  # fmt: skip
            # past the duration: Ruckig integrates from the end of the last phase
            if after.any():
                ta = times[after] - (brake[after] + last[after])
                o = owner[after]
                p[after] = _integrate(ta, self.p[o, d, 7], self.v[o, d, 7], self.a[o, d, 7], 0.0)
            braking = (brake > 0.0) & (times < brake) & ~after
            if braking.any():
                tb = times[braking]
                o = owner[braking]
                second = tb >= self.brake_t[o, d]
                tb = np.where(second, tb - self.brake_t[o, d], tb)
                i = second.astype(np.intp)
                pb, vb, ab, jb = (x[o, d, i] for x in self.brake_pvaj)
                p[braking] = _integrate(tb, pb, vb, ab, jb)
            out[:, d] = p
        return out


def _integrate(t, p0, v0, a0, j):
    """Ruckig's constant-jerk position, operation for operation."""
    return p0 + t * (v0 + t * (a0 / 2 + t * j / 6))


def sample_positions(trajectories: Sequence, times: np.ndarray) -> np.ndarray:
    """Positions [rad] (M, T, n) of ``trajectories`` at the same ``times`` [s] (T,) each."""
    times = np.asarray(times, dtype=np.float64)
    m, n_t = len(trajectories), len(times)
    if m == 0:
        return np.empty((0, n_t, 0))
    table = TrajectoryTable(trajectories)
    owner = np.repeat(np.arange(m), n_t)
    return table.positions(owner, np.tile(times, m)).reshape(m, n_t, table.n_joints)
