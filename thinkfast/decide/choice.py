"""Re-rooted motion choice: the motion whose shield meets the ball, moving or at rest.

At every belief the tree planner scores, with one value, every motion the arm could follow from
its commanded state now, and takes the best: **continue** the motion in progress, **direct
moves** (Ruckig, to the ``candidates`` goals nearest the crossing mean, always including the
nearest one) and, with ``[choice] branches``, the **tree branches** of the node the arm is at.
A motion's value is :func:`path_value.block_probability` of its sampled shield path against the
crossing Gaussian N(Y, Z, tau), the shield at path time ``s`` at ``t_plan + lag + s``. A new
motion replaces the one in progress only when it is worth ``switch_margin`` more, so equal
values never make the arm dither. Units: s, m, rad.

The options and the value in full: docs/DESIGN.md, "The re-rooted choice".
"""

from __future__ import annotations

import dataclasses
import math
from bisect import bisect_left, bisect_right
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.decide import iso_disk
from thinkfast.decide.path_value import PathValueConfig, block_probability
from thinkfast.decide.shield_paths import block_geometry, pack, shield_paths
from thinkfast.estimate.linalg import inv
from thinkfast.robot import kernels
from thinkfast.robot.batch_traj import TrajectoryTable
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.robot.steering import Steering

CONTINUE, DIRECT, BRANCH = "continue", "direct", "branch"
BATCH_SAMPLES = 768  # numpy kernels: from this many samples, paths are read in one numpy pass,
# not by at_time (below it the numpy pass costs more: docs/BENCHMARKS.md, "The tree planner's
# choice, replayed")


@dataclasses.dataclass(frozen=True)
class ChoiceConfig:
    """Motion choice of the tree planner (``[choice]`` table of the runtime configuration)."""

    candidates: int = spec(
        6, lo=1, hi=64, doc="direct moves scored per belief (goals nearest the crossing mean)"
    )
    path_dt: float = spec(
        0.02, unit="s", lo=0.002, hi=0.1, doc="sampling step of a motion's shield path"
    )
    switch_margin: float = spec(
        0.01, lo=0.0, hi=1.0, doc="a new motion must block this much more often than continuing"
    )
    horizon_sigmas: float = spec(
        5.0,
        unit="sigma",
        lo=3.0,
        doc="paths are sampled over the mean crossing time +- this many of its std",
    )
    branches: bool = spec(
        False, doc="also score the compiled child edges of the tree node the arm is at"
    )
    branch_goals: int = spec(
        4, lo=1, hi=64, doc="continuations scored per child edge end at these nearest goals"
    )
    branch_per_goal: int = spec(
        1, lo=0, hi=1000, doc="earliest continuations kept per child edge and goal (0: all)"
    )


class Option(NamedTuple):
    """One scored motion.

    Attributes:
        kind: CONTINUE, DIRECT or BRANCH.
        goal: goal index of a direct move, or of a branch's best continuation (-1 for continue).
        traj: the Ruckig trajectory of a direct move, from the commanded state at ``t_plan``
            (None otherwise).
        value: probability of blocking.
        node: the child node a branch's edge leads to (-1 otherwise).
    """

    kind: str
    goal: int
    traj: object
    value: float
    node: int = -1


class BranchPoint(NamedTuple):
    """Where compiled edges may start: ``node``'s state is (or will be) commanded at wall time
    ``t_switch`` [s]; ``pending``: the child already chosen to start there (-1: none)."""

    node: int
    t_switch: float
    pending: int = -1


class Chooser:
    """Scores motions by the moving-shield block probability (see the module doc).

    Args:
        goal_q: joint angles of every goal [rad], shape (G, >= robot.n_arm).
        goal_yz: goal points on the plane [m], shape (G, 2).
        robot: the robot (shield, kinematics).
        plane_x: the plane's x in ``base`` [m].
        ball_radius: [m].
        steer: minimum-time moves to rest for joints 1-3 (the executor's limits).
        cfg: choice parameters.
        quadrature: the path-value kernel's quadrature parameters.
    """

    def __init__(
        self, goal_q, goal_yz, robot, plane_x, ball_radius, steer: Steering, cfg,
        quadrature: PathValueConfig = PathValueConfig(),
    ):  # fmt: skip
        self.goal_q = np.asarray(goal_q, dtype=float)[:, : robot.n_arm]
        self.goal_yz = np.asarray(goal_yz, dtype=float)
        self.sampler = ShieldSampler(robot)
        self.geom = block_geometry(robot, plane_x, ball_radius)
        self.rho = self.geom.shield_radius + self.geom.ball_radius
        self._widen = self.rho**2 * np.eye(2)
        self.steer = steer
        self.cfg = cfg
        self.quadrature = quadrature
        iso_disk.warm_up()  # its table now, not in the first decision (docs/BENCHMARKS.md,
        # "Path values: moving shields": many EGM cycles)
        if kernels.compiled():  # the compiled kernels (or their disk cache) now, likewise
            from thinkfast.decide import pair_jit

            pair_jit.warm_up()

    # ------------------------------------------------------------------ candidates
    def candidate_goals(self, mean_yz: np.ndarray, cov_yz: np.ndarray) -> np.ndarray:
        """Goals to try, nearest first under the widened lateral covariance, shape (<=K,)."""
        d, m = self._distances(mean_yz, cov_yz)
        k = min(self.cfg.candidates, len(m))
        near = m.argpartition(k - 1)[:k] if k < len(m) else np.arange(len(m))
        near = near[m[near].argsort(kind="stable")]
        d *= d
        nearest = int((d[:, 0] + d[:, 1]).argmin())  # naive's goal is always a candidate
        if nearest not in near:
            near = np.concatenate(([nearest], near[:-1]))
        return near

    def _distances(self, mean_yz, cov_yz) -> tuple[np.ndarray, np.ndarray]:
        """Goal offsets from the crossing mean (G, 2) [m] and their squared Mahalanobis
        distances under the lateral covariance widened by the block radius (G,)."""
        d = self.goal_yz - np.asarray(mean_yz, dtype=float)
        s = np.asarray(cov_yz, dtype=float) + self._widen
        return d, np.einsum("gi,ij,gj->g", d, inv(s), d)

    def choose(
        self,
        crossing_mean: np.ndarray,
        crossing_cov: np.ndarray,
        approach: np.ndarray | None,
        t_belief: float,
        t_plan: float,
        lag: float,
        state: np.ndarray,
        current,
        branch_at: BranchPoint | None = None,
        table=None,
    ) -> tuple[Option, list[Option]]:
        """The best motion from the commanded ``state`` (3 n_arm,) at ``t_plan`` [s], and all
        scored.

        Args:
            crossing_mean, crossing_cov: N(Y, Z, tau) of the crossing, tau from ``t_belief``.
            approach: the ball's mean velocity at the crossing [m/s] (3,) or None.
            t_belief: time of the belief [s]. t_plan: when the chosen motion is commanded [s].
            lag: controller lag [s]. state: commanded joints 1-3 (p, v, a) at ``t_plan``.
            current: the Segment in progress (its trajectory is "continue").
            branch_at: the tree node whose child edges may start, or None (no branches).
            table: the :class:`~thinkfast.decide.branches.BranchTable` (with ``branch_at``).
        """
        mean = np.asarray(crossing_mean, dtype=float)
        goals = self.candidate_goals(mean[:2], np.asarray(crossing_cov)[:2, :2])
        goals = goals.tolist()
        moves = zip(goals, self.steer.to_rest_each(state, self.goal_q[goals]), strict=True)
        moves = [(g, traj) for g, traj in moves if traj is not None]
        trajs = [traj for _, traj in moves]
        times = self._window(mean[2], crossing_cov[2][2], t_plan + lag - t_belief)
        joints = _joint_paths(current, times + (t_plan - current.t0), trajs, times)
        values = self.score_joint_paths(
            joints, times, mean, crossing_cov, approach, t_plan + lag - t_belief
        ).tolist()
        options = [Option(CONTINUE, -1, None, values[0])] + [
            Option(DIRECT, g, traj, v) for (g, traj), v in zip(moves, values[1:], strict=True)
        ]
        if branch_at is not None and table is not None:
            options += self._branches(
                branch_at, table, mean, crossing_cov, approach, t_plan + lag - t_belief
                + (branch_at.t_switch - t_plan) - float(table.tree.node_ttc[branch_at.node]),
            )  # fmt: skip
            held = [o for o in options if o.kind == BRANCH and o.node == branch_at.pending]
            if held:  # the pending switch is the plan in progress
                options[0] = options[0]._replace(value=held[0].value)
        best = max(options[1:], key=lambda o: o.value, default=options[0])
        if not best.value > options[0].value + self.cfg.switch_margin or (
            best.kind == BRANCH and branch_at is not None and best.node == branch_at.pending
        ):
            best = options[0]
        return best, options

    def _branches(self, at: BranchPoint, table, mean, cov, approach, t_start) -> list[Option]:
        """BRANCH options: every child edge of ``at.node`` with a continuation to a nearby goal."""
        k = min(self.cfg.branch_goals, len(self.goal_yz))
        near = self.candidate_goals_k(mean[:2], np.asarray(cov)[:2, :2], k)
        bv = table.values(at.node, near, mean, cov, approach, t_start, self.quadrature)
        return [
            Option(BRANCH, int(g), None, float(v), int(c))
            for c, v, g in zip(bv.child.tolist(), bv.value.tolist(), bv.goal.tolist(), strict=True)
        ]

    def candidate_goals_k(self, mean_yz, cov_yz, k: int) -> np.ndarray:
        """The ``k`` goals nearest the crossing mean under the widened lateral covariance."""
        m = self._distances(mean_yz, cov_yz)[1]
        return m.argpartition(k - 1)[:k] if k < len(m) else np.arange(len(m))

    def _window(self, tau: float, var_tau: float, t_start: float) -> np.ndarray:
        """Sample times [s, path clock, 0 at t_plan] covering tau +- ``horizon_sigmas`` std: the
        kernel reads a path only there (before its first sample it holds the first)."""
        dt, half = self.cfg.path_dt, self.cfg.horizon_sigmas * math.sqrt(max(var_tau, 0.0))
        lo = max(math.floor((tau - half - t_start) / dt), 0)
        hi = max(math.ceil((tau + half - t_start) / dt), lo + 1)
        return np.arange(lo, hi + 1) * dt

    # ------------------------------------------------------------------ values
    def score_joint_paths(self, joints, times, mean, cov, approach, t_start) -> np.ndarray:
        """P(block) of joint 1-3 paths (M, T, n_arm) sampled at ``times`` (T,) [s, path clock]
        whose clock reads 0 at ``t_start`` [s] after the belief, shape (M,)."""
        m, n_t, n = joints.shape
        planes = np.empty((6, m * n_t))  # the packed layout, filled by rows
        self.sampler.centre_rows(joints.reshape(m * n_t, n), out=planes[:3])
        if not np.logical_and.reduce(np.isfinite(planes[:3]), axis=None):
            raise ValueError("times and centres must be finite")
        packed = pack(times, planes, self.geom)
        return block_probability(packed, mean, cov, self.geom, approach, t_start, self.quadrature)

    def score_paths(self, times, centres, mean, cov, approach, t_start) -> np.ndarray:
        """P(block) of shield-centre paths (M, T, 3) [m] in ``base``, shape (M,)."""
        packed = shield_paths(times, centres, self.geom)
        return block_probability(packed, mean, cov, self.geom, approach, t_start, self.quadrature)


def _joint_paths(current, current_times: np.ndarray, trajs: list, times: np.ndarray):
    """Joints 1-3 (1 + M, T, n): the segment in progress at ``current_times`` and ``trajs`` at
    ``times`` [s], each clipped to its trajectory (as :func:`_sample`, bit for bit: with compiled
    kernels the phases read once per trajectory and evaluated in one compiled pass,
    :mod:`traj_jit`; with numpy ones many samples in one numpy pass, few by at_time)."""
    moving = ([current.traj] if current.traj is not None else []) + list(trajs)
    # n: joints, the trajectories' (else the end state's: p, v, a)
    n_t, n = len(times), moving[0].degrees_of_freedom if moving else len(current.end) // 3
    jit = kernels.compiled()
    if not jit and len(moving) * n_t < BATCH_SAMPLES:
        flat = _flat(current.traj, current_times.tolist(), current.end)
        shared = times.tolist()
        for tr in trajs:
            flat += _flat(tr, shared, None)
        return np.array(flat, dtype=float).reshape(1 + len(trajs), n_t, n)
    out = np.empty((1 + len(trajs), n_t, n))
    first = 0 if current.traj is not None else 1
    if first:
        out[0] = np.asarray(current.end[:n], dtype=float)
    if not jit:
        table = TrajectoryTable(moving)
        owner = np.repeat(np.arange(len(moving)), n_t)
        t = np.concatenate([current_times] * (current.traj is not None) + [times] * len(trajs))
        t = np.minimum(np.maximum(t, 0.0), table.duration[owner])
        out[first:] = table.positions(owner, t).reshape(len(moving), n_t, n)
    elif moving:
        from thinkfast.robot.traj_jit import clipped_positions, phases

        t = np.empty((len(moving), n_t))
        if not first:
            t[0] = current_times
        t[1 - first :] = times
        clipped_positions(*phases(moving), t, out[first:])
    return out


def _sample(traj, times: np.ndarray, end) -> np.ndarray:
    """Joints 1-3 of ``traj`` at ``times`` [s] clipped to ``[0, duration]``, shape (T, n), one
    ``at_time`` per sample (the reference); a trajectory-less segment stays at the position
    of its ``end`` state (3n,)."""
    if traj is None:
        return np.tile(np.asarray(end[: len(end) // 3], dtype=float), (len(times), 1))
    dur = traj.duration
    rows = [traj.at_time(min(max(t, 0.0), dur))[0] for t in np.asarray(times).tolist()]
    return np.array(rows, dtype=float).reshape(-1, traj.degrees_of_freedom)


def _flat(traj, times: list, end) -> list:
    """:func:`_sample` flat (n T floats) for ``times`` ascending (a list), with one ``at_time``
    per distinct clipped time: the times at or before 0 read at 0, those at or after the end
    at the end."""
    n = len(times)
    if traj is None:
        return [float(x) for x in end[: len(end) // 3]] * n
    at, dur = traj.at_time, traj.duration
    lo = bisect_right(times, 0.0)
    hi = max(bisect_left(times, dur), lo)
    out = list(at(0.0)[0]) * lo if lo else []
    for t in times[lo:hi]:
        out += at(t)[0]
    if hi < n:
        out += at(dur)[0] * (n - hi)
    return out
