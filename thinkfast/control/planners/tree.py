"""``tree``: the re-rooted choice (:mod:`thinkfast.decide.choice`) at every belief.

The best of continuing the motion in progress (at home: waiting there), direct moves to goals
and (``[choice] branches``) the compiled child edges of the node the arm is at; a move or a
branch replaces continuing only when it is worth ``switch_margin`` more. When continuing wins
but is worth less than ``min_move_value`` (the ball comes too fast for any move to help), it
rushes to the goal nearest the most likely crossing point, as ``naive`` does. A chosen child
edge starts now (at home) or is queued on the timeline for the end of the edge in progress.
The only planner with the hedge stage before the confirmation (``[hedge] mode``).
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.planners.base import STAY, Act, Belief, EpisodeLog, Follow, Planner
from thinkfast.control.segments import EDGE, STEER, Segment
from thinkfast.control.timeline import Timeline
from thinkfast.decide.branches import BranchTable
from thinkfast.decide.choice import BRANCH, DIRECT, BranchPoint, Chooser
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.robot.model import Robot


class TreePlanner(Planner):
    """The tree planner (module doc). ``chosen``: (value, goal) of its last choice."""

    hedges = True

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, timeline: Timeline):
        super().__init__(tree, robot, cfg, timeline)
        self.chooser = Chooser(
            tree.goal_q, tree.goal_yz, robot, tree.plane_x, tree.ball_radius, timeline.steer,
            cfg.choice, cfg.path_value,
        )  # fmt: skip
        self.branches = None
        if cfg.choice.branches:
            self.branches = branch_table(tree, self.chooser.geom, cfg.choice.branch_per_goal)
        self.chosen: tuple[float, int] | None = None

    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        c = b.crossing
        if not c.ok:
            return STAY
        tl = self.timeline
        v = np.array(b.mean[3:6], dtype=float)
        v[2] -= self.cfg.filter.gravity * float(c.mean[2])  # the ball's velocity at the plane
        at = self.branch_point(b.t_now)
        best, _ = self.chooser.choose(
            c.mean, c.cov, v, b.stamp, b.t_now, self.lag, tl.state(b.t_now), tl.segment, at,
            self.branches,
        )  # fmt: skip
        goal = best.goal if best.kind in (DIRECT, BRANCH) else -1
        if best.kind != DIRECT and tl.segment.kind == STEER:
            goal = int(tl.segment.ref)  # continuing the move to this goal
        self.chosen = (float(best.value), int(goal))
        if best.kind == BRANCH:
            return Act(
                leave=True, value=best.value, follow=self.take_branch(best.node, at, b.t_now)
            )
        if best.kind != DIRECT and best.value < self.cfg.execution.min_move_value:
            # nothing reachable has value (the ball comes too fast): the paper's fallback, rush
            # to the most probable goal; a shield on its way may still catch the ball
            return self.rush(b)
        if best.kind != DIRECT:
            return STAY  # continuing (at home: waiting) is worth the most
        n = self.n_arm
        end = np.r_[self.tree.goal_q[best.goal, :n], np.zeros(2 * n)]
        seg = Segment(STEER, b.t_now, best.traj, end, best.traj.duration, best.goal)
        return Act(leave=True, value=best.value, follow=Follow(seg, None))

    def advance(self, t: float, ep: EpisodeLog) -> Follow | None:
        """At the end of the edge in progress, start the queued child edge."""
        tl = self.timeline
        if tl.pending is None:
            return None
        child, t_switch = tl.pending
        seg = tl.segment
        if seg.kind != EDGE or self.tree.compiled.node_parent[child] != seg.ref:
            return Follow(pending=None)  # the edge it was to follow was replaced
        if t >= t_switch:
            return self.start_edge(child, t_switch)
        return None

    def pending_segment(self) -> Segment | None:
        """The queued child edge as :meth:`start_edge` will start it (pure), or None."""
        tl = self.timeline
        if tl.pending is None or tl.segment.kind != EDGE:
            return None
        child, t0 = tl.pending
        if self.tree.compiled.node_parent[child] != tl.segment.ref:
            return None
        n = self.n_arm
        target = self.tree.subgoal_q[self.tree.compiled.edge_target[child], :n]
        traj = tl.steer.to_rest(tl.state(t0), target)
        if traj is None:
            return None
        return Segment(EDGE, t0, traj, np.r_[target, np.zeros(2 * n)], traj.duration, int(child))

    def resume_edge(self, q: np.ndarray) -> tuple[str, np.ndarray, int]:
        """An edge steers on to its sub-goal: resume that move."""
        seg = self.timeline.segment
        return STEER, seg.end[: self.n_arm], -1

    def value(self) -> tuple[float, int] | None:
        return self.chosen

    def reset(self) -> None:
        super().reset()
        self.chosen = None

    def branch_point(self, t_now: float) -> BranchPoint | None:
        """The tree node whose child edges can start, and when: home at rest now, or the end of
        the compiled edge in progress (still ahead); None anywhere else (off the tree)."""
        if self.branches is None:
            return None
        t = self.tree.compiled
        tl = self.timeline
        seg = tl.segment
        if seg.kind == EDGE and t_now < seg.t0 + self.tree.eps:
            if t.child_count[seg.ref] == 0:
                return None
            pending = tl.pending[0] if tl.pending is not None else -1
            return BranchPoint(int(seg.ref), seg.t0 + self.tree.eps, pending)
        if np.array_equal(seg.state(t_now), t.node_state[0]):  # e.g. after a "stay" edge
            return BranchPoint(0, t_now)
        return None

    def take_branch(self, child: int, at: BranchPoint, t_now: float) -> Follow:
        """Start the chosen child edge into ``child`` now (at home) or queue it for the end of
        the edge in progress."""
        if at.t_switch <= t_now:
            return self.start_edge(child, t_now)
        return Follow(pending=(child, at.t_switch))

    def start_edge(self, child: int, t0: float) -> Follow:
        """Follow the compiled edge into ``child`` from the commanded state at ``t0`` (the state
        of its parent node), steering on to its sub-goal after ``eps`` unless a child of it
        is taken then; nothing queued after it."""
        t = self.tree.compiled
        tl = self.timeline
        n = self.n_arm
        target = self.tree.subgoal_q[t.edge_target[child], :n]
        traj = tl.steer.to_rest(tl.state(t0), target)
        if traj is None:
            return Follow(pending=None)
        end = np.r_[target, np.zeros(2 * n)]
        seg = Segment(EDGE, t0, traj, end, traj.duration, int(child))
        return Follow(seg, None, int(t.node_parent[child]), (int(child),))


def branch_table(tree: RuntimeTree, geom, per_goal: int) -> BranchTable:
    """The tree's :class:`BranchTable`, built once per runtime tree and parameters (packing
    every continuation of the default tree takes about a second)."""
    cache = tree.__dict__.setdefault("_branch_tables", {})
    key = (geom, per_goal)
    if key not in cache:
        cache[key] = BranchTable(tree.compiled, geom, per_goal)
    return cache[key]
