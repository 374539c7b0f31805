"""``tree-rest``: the paper's planner on the at-rest values of the compiled tree.

The arm leaves home once the root of the at-rest backup blocks with at least ``min_move_value``
and its best first edge is not "stay"; every ``eps`` it takes the best child of the node it
reaches (a primitive in progress is finished), or commits to the node's best terminal edge when
that is worth more. Once committed, every belief re-targets Ruckig to the most probable goal
when it differs from the committed one (the tree is exhausted: the paper's fallback). When the
root is worth less than ``min_move_value``, it rushes to the most probable goal, re-targeted at
every belief. Its compiled edges use the robot's full limits (no ``--speed-scale``).
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.planners.base import STAY, Act, Belief, EpisodeLog, Follow, Planner
from thinkfast.control.segments import EDGE, STEER, TERMINAL, Segment, hold, move


class TreeRestPlanner(Planner):
    """The at-rest tree planner (module doc)."""

    full_limits = True

    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        self.backup(b)
        if not b.executing:
            return self._leave_home(b.t_now, ep)
        if self.timeline.segment.kind in (STEER, TERMINAL):
            # committed: follow the most probable goal as beliefs improve
            return Act(follow=self._fallback(b.t_now))
        return STAY

    def advance(self, t: float, ep: EpisodeLog) -> Follow | None:
        """Switch segments at tree-edge boundaries up to ``t`` [s]."""
        seg, path = self.timeline.segment, []
        while seg.kind == EDGE and t >= seg.t_end:
            node = seg.ref
            path.append(node)
            nxt = self._next_from(node, seg.t_end, ep)
            if nxt is None:  # no decision possible: stop at the node's state
                seg = hold(self.tree.compiled.node_state[node], seg.t_end)
                break
            seg = nxt
        if not path:
            return None
        return Follow(seg, node=path[-1], path=tuple(path))

    def _leave_home(self, t_now: float, ep: EpisodeLog) -> Act:
        d = self.decision
        if d is None or d.backup is None:
            return STAY
        b = d.backup
        if b.value[0] < self.cfg.execution.min_move_value:
            # no branch arrives in time with any chance: nothing to lose by rushing to the most
            # probable goal (a rim may still catch the ball), re-targeted at every belief
            if b.best_goal < 0:
                return STAY
            goal = int(b.best_goal)
            return Act(leave=True, value=float(b.value[0]), follow=self.steer(goal, t_now))
        first = self._next_from(0, t_now, ep)
        if first is None or (first.kind == EDGE and self._is_stay(first)):
            return STAY  # waiting at home is best: decide again at the next belief
        return Act(leave=True, value=float(b.value[0]), follow=Follow(first))

    def _is_stay(self, seg: Segment) -> bool:
        state = self.tree.compiled.node_state
        return bool(np.array_equal(state[seg.ref], state[0]))

    def _next_from(self, node: int, t0: float, ep: EpisodeLog) -> Segment | None:
        """The segment leaving ``node`` at ``t0``: best child, or best terminal when worth more."""
        t = self.tree.compiled
        d = self.decision
        if d is None or d.backup is None:
            return None
        b = d.backup
        state = t.node_state[node]
        child, term = self.tree.best_child(d, node), self.tree.best_terminal(d, node)
        if child >= 0 and (term < 0 or b.child_value[node] >= b.term_value[node]):
            target = self.tree.subgoal_q[t.edge_target[child], : self.n_arm]
            traj = self.timeline.steer.to_rest(state, target)
            if traj is not None:
                return Segment(EDGE, t0, traj, t.node_state[child], self.tree.eps, child)
        if term >= 0:
            goal = int(t.term_goal[term])
            target = self.tree.goal_q[goal, : self.n_arm]
            seg = move(self.timeline.steer, TERMINAL, state, target, t0, term)
            if seg is not None:
                ep.terminal = term
                return seg
        return None

    def _fallback(self, t_now: float) -> Follow | None:
        """Tree exhausted, ball still coming: steer to the most probable goal."""
        d = self.decision
        if d is None or d.backup is None or d.backup.best_goal < 0:
            return None
        goal = int(d.backup.best_goal)
        seg = self.timeline.segment
        current = seg.ref
        if seg.kind == TERMINAL:
            current = int(self.tree.compiled.term_goal[current])
        if current == goal:
            return None
        return self.steer(goal, t_now)
