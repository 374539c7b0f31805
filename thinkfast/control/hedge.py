"""The hedge stage: a bounded start on the early belief, before the launch is confirmed.

With ``[hedge] mode`` other than ``none`` the arm may start before the launch gate confirms:
from the first detections that make a launch likely (:mod:`thinkfast.estimate.early_belief`) it
moves towards a target chosen under that wide belief (``mean``: the nearest goal; ``tree``: the
compiled tree's best first edge), truncated so that the shield centre stays within ``bound`` (m)
of home, on a jerk-limited move that ends at rest. At the confirmation the re-rooted choice
takes over from the commanded state; a hedge ends without a commit on ``no_launch``,
``timeout`` or ``silence``, and the arm returns home. Pure logic over arrays; the executor calls
it with the times.

The targets and the two stages in full: docs/DESIGN.md, "The hedge stage".
"""

from __future__ import annotations

import dataclasses

import numpy as np

from thinkfast.config import spec
from thinkfast.control.segments import STEER, Segment
from thinkfast.decide import lookahead as lk
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.estimate import early_belief as eb
from thinkfast.estimate.crossing import Crossing
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.robot.steering import Steering, positions

HEDGE_MODES = ("none", "mean", "tree")
HEDGE, COMMIT = "hedge", "commit"  # the executor's ``stage`` ("" before either)
SCALES = np.linspace(0.0, 1.0, 65)  # fractions of the way to a target tried by the truncation
CHECK_DT = 0.008  # s: a hedge move's shield displacement is checked this often along it
PLANNED = 0.8  # commanded paths stay within this fraction of the bound, targets within 0.7:
# the rest is for the wrist's lag behind its coplanar angles and the servo's tracking error


@dataclasses.dataclass(frozen=True)
class HedgeConfig:
    """Hedge stage (``[hedge]`` table of the runtime configuration; module doc)."""

    mode: str = spec(
        "mean",
        choices=HEDGE_MODES,
        doc="none: nothing moves before the launch is confirmed; mean: hedge towards the goal "
        "nearest the early belief's crossing mean; tree: along the tree's best first edge",
    )
    bound: float = spec(
        0.10,
        unit="m",
        lo=0.0,
        hi=0.10,
        lo_open=True,
        doc="largest shield-centre displacement from home before the launch is confirmed",
    )
    terminals: bool = spec(
        False,
        doc="mode tree: home's terminal edges (direct moves to goals) are first motions too; "
        "one is taken when worth at least the best child edge",
    )
    timeout: float = spec(
        0.25,
        unit="s",
        lo=0.0,
        lo_open=True,
        doc="a hedge the launch detector has not confirmed this long after it began returns "
        "home (and no other hedge starts in that episode)",
    )


class Hedger:
    """Targets and checked moves of the hedge stage (module doc).

    Args:
        tree: the runtime tree (goals, first edges, backup).
        robot: the robot (home, shield kinematics).
        steer: minimum-time moves to rest for joints 1-3 (the executor's limits).
        cfg: hedge parameters. early: early-belief parameters.
        gravity: [m/s^2]. lag: controller lag [s].
    """

    def __init__(self, tree: RuntimeTree, robot, steer: Steering, cfg: HedgeConfig,
                 early: eb.EarlyConfig, gravity: float, lag: float,
                 foresight: lk.Foresight | None = None, min_std: float = 0.0):  # fmt: skip
        self.tree, self.steer, self.cfg, self.early = tree, steer, cfg, early
        self.gravity, self.lag = gravity, lag
        self.foresight, self.min_std = foresight, min_std  # mode tree: the look-ahead's
        self.sampler = ShieldSampler(robot)
        self.n_arm = robot.n_arm  # the joints it moves, q[:n_arm]
        self.home = np.array(robot.home[: self.n_arm], dtype=float)
        self.home_c = self.sampler.centres(self.home)
        self.yz_lo = tree.goal_yz.min(axis=0)
        self.yz_hi = tree.goal_yz.max(axis=0)

    def belief(self, points: list) -> tuple[eb.EarlyFit | None, Crossing | None]:
        """The early belief from the launch detector's detections ``points`` and its crossing
        (None, None when no launch is likely)."""
        fit = eb.early_fit(
            points, self.early, self.tree.plane_x, self.yz_lo, self.yz_hi, self.gravity
        )
        if not eb.likely_launch(fit, self.early):
            return None, None
        c = self.tree.crossing(fit.mean, fit.cov, self.gravity)
        return (fit, c) if c.ok else (None, None)

    def target(
        self, c: Crossing, stamp: float, t_now: float, fit: eb.EarlyFit | None = None
    ) -> np.ndarray:
        """Joint 1-3 target [rad] (n_arm,) of the hedge under the crossing ``c`` (belief at
        ``stamp``, planned at ``t_now``; ``fit``: the early belief, for the look-ahead),
        truncated to the bound; home to stay."""
        if self.cfg.mode == "mean":
            q = self.tree.goal_q[self.tree.nearest_goal(c.mean[:2]), : self.n_arm]
        else:
            ahead = None
            if self.foresight is not None and fit is not None:
                ahead = lk.ahead(
                    fit.mean, fit.cov, c.cov, self.tree.commit_horizon(0, t_now, t_now),
                    self.foresight, self.tree.plane_x, self.min_std,
                )  # fmt: skip
            d = self.tree.decide(c, stamp, t_now, self.lag, ahead)
            if d.backup is None:
                return self.home.copy()
            t = self.tree.compiled
            child = self.tree.best_child(d, 0)
            term = self.tree.best_terminal(d, 0) if self.cfg.terminals else -1
            if term >= 0 and (child < 0 or d.backup.term_value[0] >= d.backup.child_value[0]):
                q = self.tree.goal_q[t.term_goal[term], : self.n_arm]  # a move to a goal
            elif child < 0:
                return self.home.copy()
            else:
                q = self.tree.subgoal_q[t.edge_target[child], : self.n_arm]
        return self.truncate(np.asarray(q, dtype=float))

    def displacement(self, q: np.ndarray) -> np.ndarray:
        """Shield-centre distance from home [m] for joints 1-3 ``q`` (..., n_arm), shape (...)."""
        return np.linalg.norm(self.sampler.centres(q) - self.home_c, axis=-1)

    def truncate(self, q: np.ndarray) -> np.ndarray:
        """The furthest point of the joint-space segment home -> ``q`` whose shield stays within
        the bound all the way (checked at :data:`SCALES`, within 0.7 of the bound)."""
        pts = self.home + SCALES[:, None] * (q - self.home)
        ok = self.displacement(pts) <= (PLANNED - 0.1) * self.cfg.bound
        k = len(ok) if ok.all() else int(np.argmin(ok))  # the first fraction out of bounds
        return pts[max(k - 1, 0)]

    def plan(self, state: np.ndarray, target: np.ndarray, t: float) -> Segment | None:
        """A move to rest at ``target`` from the commanded ``state`` (3 n_arm,) at ``t`` [s] whose
        sampled shield path stays within :data:`PLANNED` of the bound; None when Ruckig fails
        or it would not."""
        traj = self.steer.to_rest(state, target)
        if traj is None or not self.within(traj):
            return None
        end = np.r_[target, np.zeros(2 * self.n_arm)]
        return Segment(STEER, t, traj, end, traj.duration, -1)

    def within(self, traj) -> bool:
        """The joint 1-3 trajectory's shield stays within :data:`PLANNED` of the bound (sampled
        every :data:`CHECK_DT` and at its end)."""
        times = np.r_[np.arange(0.0, traj.duration, CHECK_DT), traj.duration]
        return bool(self.displacement(positions(traj, times)).max() <= PLANNED * self.cfg.bound)
