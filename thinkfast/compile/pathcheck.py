"""Validity of one primitive: position limits along it, collisions at a guaranteed resolution.

The primitive (joints 1-3 from Ruckig, joints 4-6 by the coplanar wrist rule) is sampled every
``sample_dt``. Position limits (with a margin) hold on the samples and, for joints 1-3, at Ruckig's
exact extrema. Collision checks are placed so that no point of the robot moves more than
``resolution`` between two checks. Between two samples a link moves rigidly by (dR, dt); a point
within rho of the link origin (rho from the link's sphere cover) moves at most
|dt| + 2 sin(theta / 2) rho, theta the angle of dR. The largest such bound over links is
accumulated along the samples, which are refined until one step moves no point more than half the
resolution (the motion between samples is then well resolved, as it is smooth).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from ruckig import Trajectory

from thinkfast.robot.batch_collision import BatchCollision
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import position_range, positions
from thinkfast.robot.wrist import CoplanarWrist

MAX_SAMPLES = 200_000
POINT_SPEED_MAX = 50.0  # m/s: no point of this arm moves a tenth of this fast


class PathResult(NamedTuple):
    """Outcome of :meth:`PathChecker.check`.

    Attributes:
        ok: the primitive is valid.
        reason: "" when valid, else "position_limit", "wrist_limit", "wrist_singularity" or
            "collision" (the pair is in ``detail``).
        wrist_end: wrist angles [rad] (3,) at the end of the checked span.
        checks: number of collision checks made.
        detail: the colliding pair or the violated joint, for reports.
    """

    ok: bool
    reason: str
    wrist_end: np.ndarray
    checks: int
    detail: str = ""


def step_motion(poses: dict[str, np.ndarray], extent: dict[str, float]) -> np.ndarray:
    """Largest motion [m] (N - 1,) of any robot point between consecutive posed samples.

    Args:
        poses: link poses (N, 4, 4) in ``base``.
        extent: per link, radius [m] around its origin that holds the whole link.
    """
    worst = None
    for link, rho in extent.items():
        P = poses[link]
        dt = np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1)
        trace = np.einsum("nij,nij->n", P[:-1, :3, :3], P[1:, :3, :3])  # tr(R_k^T R_k+1)
        chord = np.sqrt(np.maximum(3.0 - trace, 0.0))  # 2 sin(theta / 2)
        m = dt + chord * rho
        worst = m if worst is None else np.maximum(worst, m)
    return worst


class PathChecker:
    """Checks primitives of one robot (one per process; holds fcl state).

    Args:
        robot: the robot.
        resolution: largest motion [m] of any robot point between two collision checks.
        position_margin: distance [rad] kept from the URDF position limits.
        sample_dt: base sampling step [s] for limits and check placement.
    """

    def __init__(self, robot: Robot, resolution: float, position_margin: float, sample_dt: float):
        self.robot = robot
        self.resolution = resolution
        self.sample_dt = sample_dt
        self.lower = robot.q_lower + position_margin
        self.upper = robot.q_upper - position_margin
        self.checker = CollisionChecker(robot)
        self.batch = BatchCollision(self.checker)
        self.wrist = CoplanarWrist(robot)
        self.extent = self.batch.link_extent

    def sample(self, traj: Trajectory, t_end: float, wrist_prev: np.ndarray, dt: float):
        """Times (N,), all-joint positions (N, 6) over [0, t_end] every ``dt`` at most."""
        n = max(int(np.ceil(t_end / dt - 1e-9)), 1) + 1
        t = np.linspace(0.0, t_end, n)
        q123 = positions(traj, t)
        return t, np.column_stack([q123, self.wrist.solve(q123, wrist_prev)])

    def check(self, traj: Trajectory, t_end: float, wrist_prev: np.ndarray) -> PathResult:
        """Validate ``traj`` over [0, t_end] [s], the wrist starting from ``wrist_prev`` (3,)."""
        dt = self.sample_dt
        while True:
            t, q = self.sample(traj, t_end, wrist_prev, dt)
            poses = self.batch.fk.link_poses(q)
            step = step_motion(poses, self.extent)
            worst = float(step.max()) if len(step) else 0.0
            if worst > POINT_SPEED_MAX * (t[1] - t[0] if len(t) > 1 else dt):
                # the coplanar wrist rule passing (near) its singularity: it would whip the wrist
                # round faster than any arm moves; a physical test, the same at every resolution
                return PathResult(False, "wrist_singularity", q[-1, 3:], 0, "wrist flips")
            if worst <= 0.5 * self.resolution:
                break
            dt = dt / np.ceil(2.0 * worst / self.resolution)
            if t_end / dt > MAX_SAMPLES:
                return PathResult(False, "wrist_singularity", q[-1, 3:], 0, "wrist flips")
        lo, hi = position_range(traj, t_end, q[:, :3])
        names = self.robot.joint_names
        for k in range(3):
            if lo[k] < self.lower[k] or hi[k] > self.upper[k]:
                return PathResult(False, "position_limit", q[-1, 3:], 0, names[k])
        wrist_lo, wrist_hi = q[:, 3:].min(axis=0), q[:, 3:].max(axis=0)
        for k in range(3, 6):
            if wrist_lo[k - 3] < self.lower[k] or wrist_hi[k - 3] > self.upper[k]:
                return PathResult(False, "wrist_limit", q[-1, 3:], 0, names[k])
        # first sample of every half-resolution bucket: consecutive checks <= resolution apart
        travelled = np.r_[0.0, np.cumsum(step)]
        bucket = np.floor(travelled / (0.5 * self.resolution))
        idx = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
        if idx[-1] != len(q) - 1:
            idx = np.r_[idx, len(q) - 1]
        hit = self.batch.first_collision(q[idx], {k: v[idx] for k, v in poses.items()})
        if hit is not None:
            return PathResult(False, "collision", q[-1, 3:], len(idx), " / ".join(hit.pair))
        return PathResult(True, "", q[-1, 3:].copy(), len(idx))
