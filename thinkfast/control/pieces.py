"""Joint 1-3 motion as exact cubic pieces: a Ruckig trajectory's phases, or a planner's own
piecewise-constant-jerk path (an optimal control problem's solution), in one form that the plan
vector carries to the reply process (:mod:`thinkfast.control.plan`) and that a
:class:`~thinkfast.control.segments.Segment` can hold in place of a Ruckig trajectory.
"""

from __future__ import annotations

import bisect

import numpy as np

N_ARM = 3  # joints 1-3: the plan vector's layout (robot.n_arm of every robot here)
# cubic pieces per joint: a Ruckig trajectory needs 10 (2 of a brake pre-trajectory, 7 phases,
# the end); an optimisation planner's path its intervals, a stop's 10 and the end
K_MAX = 40


class Pieces:
    """A Ruckig trajectory of joints 1-3 as cubic pieces; ``at_time`` and ``duration`` as
    Ruckig's (within rounding: the same formulas).

    Args:
        start: piece start times [s] (N_ARM, K_MAX), +inf past the last piece of a joint.
        coef: (p, v, a, j) at each piece's start (N_ARM, K_MAX, 4).
        duration: the trajectory's duration [s].
    """

    def __init__(self, start: np.ndarray, coef: np.ndarray, duration: float):
        self.start = [list(map(float, row)) for row in start]
        self.coef = [[tuple(map(float, c)) for c in row] for row in coef]
        self.duration = float(duration)

    @classmethod
    def of(cls, traj) -> tuple[np.ndarray, np.ndarray]:
        """(start, coef) arrays (N_ARM, K_MAX) and (N_ARM, K_MAX, 4) of ``traj``: a
        :class:`Pieces`, or a one-section Ruckig trajectory (``to_rest``'s)."""
        if isinstance(traj, Pieces):
            return traj.arrays()
        start = np.full((N_ARM, K_MAX), np.inf)
        coef = np.zeros((N_ARM, K_MAX, 4))
        for k, pr in enumerate(traj.profiles[0]):
            rows: list[tuple[float, float, float, float, float]] = []
            b, tb = pr.brake, pr.brake.duration
            if tb > 0.0:
                rows.append((0.0, b.p[0], b.v[0], b.a[0], b.j[0]))
                rows.append((b.t[0], b.p[1], b.v[1], b.a[1], b.j[1]))
            t_sum = np.cumsum(pr.t)
            for i in range(7):
                rows.append((tb + (t_sum[i - 1] if i else 0.0), pr.p[i], pr.v[i], pr.a[i], pr.j[i]))
            rows.append((tb + t_sum[6], pr.p[7], pr.v[7], pr.a[7], 0.0))
            arr = np.array(rows)
            start[k, : len(rows)] = arr[:, 0]
            coef[k, : len(rows)] = arr[:, 1:]
        return start, coef

    def at_time(self, s: float):
        """Positions, velocities, accelerations (3 lists of N_ARM) at ``s`` [s] from the start."""
        p, v, a = [], [], []
        for starts, coefs in zip(self.start, self.coef, strict=True):
            i = max(bisect.bisect_right(starts, s) - 1, 0)
            h = s - starts[i]
            p0, v0, a0, j = coefs[i]
            p.append(p0 + h * (v0 + h * (a0 / 2 + h * j / 6)))
            v.append(v0 + h * (a0 + h * j / 2))
            a.append(a0 + h * j)
        return p, v, a

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(start, coef) as :meth:`of` gives them."""
        start = np.full((N_ARM, K_MAX), np.inf)
        coef = np.zeros((N_ARM, K_MAX, 4))
        for k, (starts, coefs) in enumerate(zip(self.start, self.coef, strict=True)):
            m = min(len(starts), K_MAX)
            start[k, :m] = starts[:m]
            coef[k, :m] = coefs[:m]
        return start, coef

    @classmethod
    def from_rows(cls, rows: list[np.ndarray], duration: float) -> Pieces:
        """Pieces from one (K, 5) array per joint of (start time, p, v, a, j) rows, starts
        increasing from 0, the last row the state held from then on (j = 0).

        Raises:
            ValueError: a joint has more than K_MAX rows.
        """
        if len(rows) != N_ARM or any(len(r) > K_MAX for r in rows):
            raise ValueError(f"{N_ARM} joints of at most {K_MAX} pieces each")
        start = np.full((N_ARM, K_MAX), np.inf)
        coef = np.zeros((N_ARM, K_MAX, 4))
        for k, r in enumerate(rows):
            r = np.asarray(r, dtype=float)
            start[k, : len(r)] = r[:, 0]
            coef[k, : len(r)] = r[:, 1:]
        return cls(start, coef, duration)
