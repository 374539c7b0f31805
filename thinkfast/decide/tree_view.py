"""Belief to decision: the crossing distribution, every terminal edge's value, the backup.

Pure computation over the tree arrays; the clocks come in as arguments:

- ``t_belief``: time of the belief (the stamp of the last measurement) [s];
- ``t_start``: wall time at which motion started (or would start now) [s];
- ``lag``: controller lag [s]: a setpoint commanded at t is reached at t + lag.

A terminal edge arrives (physically) at ``t_start + lag + term_arrival``; its remaining time from
the belief's time is compared with the crossing time tau (plus the value margin).

Values are QMDP's (every node under today's belief, max backup) or, given the belief the
coming detections make (:class:`~thinkfast.decide.lookahead.Ahead`), the one-step look-ahead
at the children of the node where the arm next chooses (:mod:`thinkfast.decide.lookahead`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.decide import backup as bk
from thinkfast.decide import lookahead as lk
from thinkfast.decide import values as vl
from thinkfast.errors import RobotModelError
from thinkfast.estimate import crossing as delta
from thinkfast.robot import kernels
from thinkfast.tree.action_tree import ActionTree
from thinkfast.tree.provenance import Provenance

BALL_RADIUS = 0.0335  # m, tennis ball (docs/FACTS.md); counts towards the blocking radius


class Decision(NamedTuple):
    """One evaluation of the tree under a belief.

    Attributes:
        crossing: the plane-crossing Gaussian (``crossing.ok`` False: no decision made).
        backup: node values, best child and terminal values per node, most probable goal.
        term_value: value of every terminal edge, shape (T,).
        t_belief: time of the belief [s].
    """

    crossing: delta.Crossing
    backup: bk.Backup | None
    term_value: np.ndarray | None
    t_belief: float


class RuntimeTree:
    """A loaded tree with the layouts the value and backup kernels need.

    Args:
        tree: the compiled tree.
        value_cfg: terminal-value parameters.
        block_radius: largest distance [m] from a goal at which the crossing ball is blocked
            (shield radius + ball radius).
    """

    def __init__(self, tree: ActionTree, value_cfg: vl.ValueConfig, block_radius: float):
        self.compiled = tree  # the ActionTree's arrays
        prov = Provenance.of(tree.meta)
        self.eps = prov.eps
        self.plane_distance = prov.plane_x
        self.plane_x = self.plane_distance  # the plane is x = distance in the plane's frame
        self.plane = prov.plane  # its pose in base (PlanePose): the run's frame
        self.ball_radius = BALL_RADIUS
        self.goal_q = tree.goal_q
        self.goal_yz = tree.goal_yz
        self.subgoal_q = tree.goal_q[tree.subgoal_goal]
        self.vlay = vl.layout(tree.goal_yz, tree.term_goal, block_radius, value_cfg)
        self.blay = bk.backup_layout(
            tree.node_depth, tree.child_start, tree.child_count, tree.term_start, tree.term_count
        )
        if kernels.compiled():  # the compiled lookup and backup now, not in the first decision
            from thinkfast.decide import tree_jit

            tree_jit.warm_up()

    def crossing(self, mean: np.ndarray, cov: np.ndarray, gravity: float) -> delta.Crossing:
        """Plane crossing of the ball belief N(mean, cov)."""
        return delta.crossing(mean, cov, self.plane_distance, gravity)

    def decide(
        self, c: delta.Crossing, t_belief: float, t_start: float, lag: float,
        ahead: lk.Ahead | None = None, node: int = 0,
    ) -> Decision:  # fmt: skip
        """Values of every branch for the crossing ``c`` (see the module doc for the clocks).

        With ``ahead`` (the crossing belief when the children of ``node`` end), those children
        are valued by the look-ahead (:func:`~thinkfast.decide.lookahead.lookahead_backup`) and
        ``node`` by the best of them and
        its own terminal edges; every other node keeps its QMDP value.
        """
        if not c.ok:
            return Decision(c, None, None, t_belief)
        remaining = self.compiled.term_arrival + (t_start + lag - t_belief)
        tv = vl.terminal_values(self.vlay, c.mean, c.cov, remaining)
        back = bk.backup(self.blay, tv.value, tv.goal_mass)
        if ahead is not None and self.blay.child_count[node] > 0:
            back = lk.lookahead_backup(self.vlay, self.blay, back, c.mean, ahead, remaining, node)
        return Decision(c, back, tv.value, t_belief)

    def commit_horizon(self, node: int, t_start: float, t_now: float) -> float:
        """Time [s] from ``t_now`` until the children of ``node`` end (the arm chooses their
        continuations then) for a motion that left home at ``t_start``; 0 without children."""
        t = self.compiled
        if t.child_count[node] == 0:
            return 0.0
        return float(t_start + t.node_ttc[t.child_start[node]] - t_now)

    def best_child(self, d: Decision, node: int) -> int:
        """Child of ``node`` with the highest value under ``d`` (-1 if none)."""
        return bk.best_child(self.blay, d.backup.value, node)

    def best_terminal(self, d: Decision, node: int) -> int:
        """Terminal edge of ``node`` with the highest value under ``d`` (-1 if none)."""
        return bk.best_terminal(self.blay, d.term_value, node)

    def nearest_goal(self, yz: np.ndarray) -> int:
        """Goal nearest the plane point ``yz`` (2,) [m]."""
        return int(np.argmin(np.sum(np.square(self.goal_yz - yz), axis=1)))


def runtime_tree(tree: ActionTree, robot, cfg) -> RuntimeTree:
    """The runtime view of ``tree`` for ``robot``: blocks within shield + ball radius.

    Raises:
        RobotModelError: the tree's node states are not of ``robot.n_arm`` joints (p, v, a) or
            its configurations not of ``robot.n_joints``: the tree moves other joints than the
            robot's positioning ones.
    """
    arm, joints = tree.node_state.shape[1] // 3, tree.node_q.shape[1]
    if (arm, joints) != (robot.n_arm, robot.n_joints):
        raise RobotModelError(
            f"{robot.toml_path}: the tree plans {arm} of {joints} joints, the robot positions "
            f"the shield with {robot.n_arm} of {robot.n_joints} (positioning_joints)"
        )
    return RuntimeTree(tree, cfg.value, robot.shield_radius + BALL_RADIUS)
