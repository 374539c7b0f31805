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
        # every phase list read once into one array (a numpy call per field, not per profile)
        profs = [prof for traj in self.trajectories for prof in traj.profiles[0]]
        self.duration = np.array([traj.duration for traj in self.trajectories], dtype=float)
        t = np.array([prof.t for prof in profs], dtype=float).reshape(m, n, 7)
        self.t_sum = np.cumsum(t, axis=2)  # partial_sum: sequential, as in Ruckig
        self.jerk = np.zeros((m, n, 8))  # phase 7 (held end) has no jerk
        self.jerk[:, :, :7] = np.array([prof.j for prof in profs], dtype=float).reshape(m, n, 7)
        self.p, self.v, self.a = (
            np.array([getattr(prof, x) for prof in profs], dtype=float).reshape(m, n, 8)
            for x in "pva"
        )
        self.brake = np.zeros((m, n))  # brake duration [s] (0: none)
        self.brake_t = np.zeros((m, n))  # end of the first brake phase [s]
        self.brake_pvaj = np.zeros((4, m, n, 2))
        brakes = [(i, prof.brake) for i, prof in enumerate(profs)]
        brakes = [(i, b) for i, b in brakes if b.duration > 0.0]
        if brakes:
            k, d = np.divmod(np.array([i for i, _ in brakes]), max(n, 1))
            self.brake[k, d] = [b.duration for _, b in brakes]
            self.brake_t[k, d] = [b.t[0] for _, b in brakes]
            self.brake_pvaj[:, k, d] = np.array(
                [(b.p, b.v, b.a, b.j) for _, b in brakes], dtype=float
            ).transpose(1, 0, 2)

    def positions(self, owner: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Positions [rad] (S, n): trajectory ``owner[s]`` at ``times[s]`` [s], each (S,)."""
        owner = np.asarray(owner, dtype=np.intp)
        times = np.asarray(times, dtype=np.float64)
        n = self.n_joints
        t_sum = self.t_sum[owner]  # (S, n, 7)
        last = t_sum[:, :, 6]
        brake = self.brake[owner]  # (S, n)
        tt = times[:, None]
        t = np.where(brake > 0.0, tt - brake, tt)  # past the brake (fixed below)
        phase = np.count_nonzero(t_sum <= t[:, :, None], axis=2)  # upper_bound
        before = np.take_along_axis(t_sum, np.maximum(phase - 1, 0)[:, :, None], axis=2)
        local = np.where(phase > 0, t - before[:, :, 0], t)
        held = t >= last
        phase[held] = 7
        local[held] = (t - last)[held]
        flat = (owner[:, None] * n + np.arange(n)) * 8 + phase  # (S, n) into (M, n, 8)
        p = _integrate(local, self.p.take(flat), self.v.take(flat), self.a.take(flat),
                       self.jerk.take(flat))  # fmt: skip
        # past the duration: Ruckig integrates from the end of the last phase
        after = times >= self.duration[owner]
        if after.any():
            ta = tt[after] - (brake[after] + last[after])
            o = owner[after]
            p[after] = _integrate(ta, self.p[o, :, 7], self.v[o, :, 7], self.a[o, :, 7], 0.0)
        braking = (brake > 0.0) & (tt < brake)
        braking &= ~after[:, None]
        if braking.any():
            s, d = np.nonzero(braking)
            tb = times[s]
            o = owner[s]
            second = tb >= self.brake_t[o, d]
            tb = np.where(second, tb - self.brake_t[o, d], tb)
            i = second.astype(np.intp)
            pb, vb, ab, jb = (x[o, d, i] for x in self.brake_pvaj)
            p[s, d] = _integrate(tb, pb, vb, ab, jb)
        return p


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
