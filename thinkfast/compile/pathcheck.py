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
from thinkfast.robot.batch_fk import assemble
from thinkfast.robot.batch_traj import TrajectoryTable
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import position_range, positions
from thinkfast.robot.wrist import CoplanarWrist

MAX_SAMPLES = 200_000
GROUP_SAMPLES = 4096  # samples per numpy pass of check_many (larger ones leave the cache)
CHECK_ROWS = 8192  # collision checks per batch of check_many
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


def step_motion(
    poses: dict[str, np.ndarray], extent: dict[str, float], starts: np.ndarray | None = None
) -> np.ndarray:
    """Largest motion [m] (N - 1,) of any robot point between consecutive posed samples.

    Args:
        poses: link poses (N, 4, 4) in ``base``.
        extent: per link, radius [m] around its origin that holds the whole link.
        starts: where each of several paths begins in the samples (P,) (default: one path);
            the steps between paths are left out, (N - P,).
    """
    worst = None
    for link, rho in extent.items():
        P = poses[link]
        dt = np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1)
        trace = np.einsum("nij,nij->n", P[:-1, :3, :3], P[1:, :3, :3])  # tr(R_k^T R_k+1)
        chord = np.sqrt(np.maximum(3.0 - trace, 0.0))  # 2 sin(theta / 2)
        m = dt + chord * rho
        worst = m if worst is None else np.maximum(worst, m)
    if starts is not None and len(starts) > 1:
        keep = np.ones(len(worst), dtype=bool)
        keep[np.asarray(starts[1:]) - 1] = False
        worst = worst[keep]
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
        self.n_arm = robot.n_arm  # q[:n_arm] from the primitive, q[n_arm:] by the wrist rule
        self.resolution = resolution
        self.sample_dt = sample_dt
        self.lower = robot.q_lower + position_margin
        self.upper = robot.q_upper - position_margin
        self.checker = CollisionChecker(robot)
        self.batch = BatchCollision(self.checker)
        self.wrist = CoplanarWrist(robot)
        self.extent = self.batch.link_extent

    def sample(self, traj: Trajectory, t_end: float, wrist_prev: np.ndarray, dt: float):
        """Times (N,), all-joint positions (N, n_joints) over [0, t_end] every ``dt`` at most."""
        n = max(int(np.ceil(t_end / dt - 1e-9)), 1) + 1
        t = np.linspace(0.0, t_end, n)
        q123 = positions(traj, t)
        return t, np.column_stack([q123, self.wrist.solve(q123, wrist_prev)])

    def check(self, traj: Trajectory, t_end: float, wrist_prev: np.ndarray) -> PathResult:
        """Validate ``traj`` over [0, t_end] [s], the wrist starting from ``wrist_prev``
        (n_joints - n_arm,)."""
        return self.check_many([traj], [t_end], np.asarray(wrist_prev, dtype=float)[None])[0]

    def check_many(
        self, trajs, t_end, wrist_prev: np.ndarray, table: TrajectoryTable | None = None
    ) -> list[PathResult]:
        """:meth:`check` of many primitives at once (the same results, one batch of numpy work).

        Args:
            trajs: Ruckig trajectories (M). t_end: checked span of each [s] (M,).
            wrist_prev: wrist angles [rad] (M, n_joints - n_arm) at the start of each.
            table: ``TrajectoryTable(trajs)`` when the caller has it already.
        """
        table = TrajectoryTable(trajs) if table is None else table
        spans = [float(x) for x in t_end]
        n_wrist = self.robot.n_joints - self.n_arm
        wrist_prev = np.asarray(wrist_prev, dtype=float).reshape(-1, n_wrist)
        out: list[PathResult | None] = [None] * len(spans)
        checks: list = []
        group: list[int] = []
        load = 0.0
        for m, span in enumerate(spans):  # groups of about GROUP_SAMPLES keep numpy in cache
            group.append(m)
            load += span / self.sample_dt + 2.0
            if load >= GROUP_SAMPLES or m == len(spans) - 1:
                self._sample_group(table, group, spans, wrist_prev, out, checks)
                group, load = [], 0.0
            if sum(len(c[2]) for c in checks) >= CHECK_ROWS or m == len(spans) - 1:
                self._collisions(checks, out)
                checks = []
        return out

    def _sample_group(self, table, todo: list, spans, wrist_prev, out: list, checks: list):
        """Sample primitives ``todo`` until resolved; limit failures go to ``out``, the rest
        to ``checks`` as (index, wrist at the end, checked joints, their link poses)."""
        dt, n = {m: self.sample_dt for m in todo}, self.n_arm
        while todo:
            batch = sample_paths(table, self.wrist, todo, spans, dt, wrist_prev)
            step = step_motion(batch.poses, self.extent, batch.starts)
            again = []
            for k, m in enumerate(todo):
                s = slice(batch.starts[k], batch.starts[k] + batch.counts[k])
                st = step[s.start - k : s.stop - k - 1]
                worst = float(st.max()) if len(st) else 0.0
                t = batch.t[s]
                q = batch.q[s]
                if worst > POINT_SPEED_MAX * (t[1] - t[0] if len(t) > 1 else dt[m]):
                    # the coplanar wrist rule passing (near) its singularity: it would whip the
                    # wrist round faster than any arm moves; a physical test, the same at every
                    # resolution
                    out[m] = PathResult(False, "wrist_singularity", q[-1, n:], 0, "wrist flips")
                elif worst <= 0.5 * self.resolution:
                    res, idx = self._limits_and_checks(table.trajectories[m], spans[m], q, st)
                    out[m] = res
                    if res is None:
                        rows = idx + s.start
                        poses = {link: P[rows] for link, P in batch.poses.items()}
                        checks.append((m, q[-1, n:].copy(), q[idx], poses))
                else:
                    dt[m] = dt[m] / np.ceil(2.0 * worst / self.resolution)
                    if spans[m] / dt[m] > MAX_SAMPLES:
                        out[m] = PathResult(False, "wrist_singularity", q[-1, n:], 0, "wrist flips")
                    else:
                        again.append(m)
            todo = again

    def _limits_and_checks(self, traj, t_end: float, q: np.ndarray, step: np.ndarray):
        """(a failed PathResult, None) at a limit, else (None, indices of the checked samples)."""
        n = self.n_arm
        lo, hi = position_range(traj, t_end, q[:, :n])
        names = self.robot.joint_names
        for k in range(n):
            if lo[k] < self.lower[k] or hi[k] > self.upper[k]:
                return PathResult(False, "position_limit", q[-1, n:], 0, names[k]), None
        wrist_lo, wrist_hi = q[:, n:].min(axis=0), q[:, n:].max(axis=0)
        for k in range(n, len(names)):
            if wrist_lo[k - n] < self.lower[k] or wrist_hi[k - n] > self.upper[k]:
                return PathResult(False, "wrist_limit", q[-1, n:], 0, names[k]), None
        # first sample of every half-resolution bucket: consecutive checks <= resolution apart
        travelled = np.r_[0.0, np.cumsum(step)]
        bucket = np.floor(travelled / (0.5 * self.resolution))
        idx = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
        if idx[-1] != len(q) - 1:
            idx = np.r_[idx, len(q) - 1]
        return None, idx

    def _collisions(self, checks: list, out: list) -> None:
        """Collision-check the chosen samples of every primitive in ``checks`` at once."""
        if not checks:
            return
        q = np.concatenate([c[2] for c in checks])
        poses = {k: np.concatenate([c[3][k] for c in checks]) for k in checks[0][3]}
        counts = np.array([len(c[2]) for c in checks])
        hits = self.batch.first_collisions(q, np.cumsum(counts) - counts, poses)
        for (m, wrist_end, qc, _), hit in zip(checks, hits, strict=True):
            if hit is not None:
                out[m] = PathResult(False, "collision", wrist_end, len(qc), " / ".join(hit.pair))
            else:
                out[m] = PathResult(True, "", wrist_end, len(qc))


class SampledPaths(NamedTuple):
    """Samples of several primitives, one after another: times [s] (S,), all joints [rad]
    (S, n_joints), each primitive's first sample (P,) and sample count (P,), link poses
    (S, 4, 4)."""

    t: np.ndarray
    q: np.ndarray
    starts: np.ndarray
    counts: np.ndarray
    poses: dict[str, np.ndarray]


def sample_paths(table, wrist, which, spans, dt, wrist_prev) -> SampledPaths:
    """Primitives ``which`` of ``table`` over [0, spans[m]] every ``dt[m]`` at most, the wrist
    by the coplanar rule from ``wrist_prev[m]`` (as :meth:`PathChecker.sample`, bit for bit)."""
    times = []
    for m in which:
        n = max(int(np.ceil(spans[m] / dt[m] - 1e-9)), 1) + 1
        times.append(np.linspace(0.0, spans[m], n))
    counts = np.array([len(t) for t in times])
    starts = np.cumsum(counts) - counts
    t = np.concatenate(times)
    n = table.n_joints  # the primitives' joints; the wrist's follow them
    q = np.zeros((len(t), n + wrist_prev.shape[-1]))
    q[:, :n] = table.positions(np.repeat(np.asarray(which), counts), t)
    early = wrist.fk.frames(q, until="link_3")  # joints 1-3 only: shared with the full FK
    q[:, n:] = wrist.solve_paths(q[:, :n], starts, wrist_prev[which], early)
    return SampledPaths(t, q, starts, counts, assemble(*wrist.fk.frames(q, resume=early)))
