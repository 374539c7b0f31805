"""The paper's at-rest tree planner (``tree-rest``) follows the tree edge by edge."""

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import EXECUTING, Executor
from thinkfast.control.segments import EDGE, Segment
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.estimate import filter as kf
from thinkfast.tree.file import load_tree

CFG = RunConfig()


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


def test_tree_rest_takes_the_next_edge_when_the_one_in_progress_ends(rtree, robot):
    t = rtree.compiled
    child = int(t.child_start[0])  # a first-level node, reached by an edge from home
    assert t.child_count[0] > 0 and t.child_count[child] + t.term_count[child] > 0
    ex = Executor(rtree, robot, CFG, "tree-rest")
    ex.start_from(robot.home, 0.0)
    # a slow throw towards the middle of the goal grid: the tree's values are worth something
    mid = rtree.goal_yz.mean(axis=0)
    belief = kf.empty(CFG.filter)
    belief = belief._replace(
        mean=np.array([4.0, mid[0], mid[1], -5.0, 0.0, 1.0]),
        cov=np.diag([1e-4] * 3 + [1e-2] * 3),
        n_meas=10,
    )
    c = rtree.crossing(belief.mean, belief.cov, CFG.filter.gravity)
    assert c.ok
    ex.gate.belief = belief
    ex.planner.decision = rtree.decide(c, 0.0, 0.0, ex.lag)
    ex.mode = EXECUTING
    ex.gate.t_last_det = rtree.eps  # the ball is still seen and still coming
    ex.episode.t_cross = 5.0
    traj = ex.timeline.steer.to_rest(t.node_state[0], rtree.subgoal_q[t.edge_target[child], :3])
    ex.timeline.segment = Segment(EDGE, 0.0, traj, t.node_state[child], rtree.eps, child)
    ex.setpoint(rtree.eps + 0.004)
    assert ex.node == child and ex.episode.path == [child]
    assert ex.segment.ref != child or ex.segment.kind != EDGE  # it moved on from the node
