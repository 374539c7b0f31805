"""One Ruckig wrapper: the runtime's edges are the compiler's, bit for bit; one failure contract."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.errors import NoSolutionError
from thinkfast.robot.steering import Steering, state_at


@pytest.fixture(scope="module")
def executor(small_tree_015, robot):
    from thinkfast.control.config import RunConfig
    from thinkfast.control.executor import Executor
    from thinkfast.decide.tree_view import runtime_tree
    from thinkfast.tree.file import load_tree

    cfg = RunConfig()
    return Executor(runtime_tree(load_tree(small_tree_015), robot, cfg), robot, cfg, "tree-rest")


def test_runtime_edges_are_the_compiled_edges(executor):
    """The executor re-solves a compiled edge from its parent's stored state (tree-rest and
    branches follow edges so): where the compiler stopped it, eps later or at rest, the runtime
    motion is exactly the stored child state."""
    rt = executor.tree
    t, eps = rt.compiled, rt.eps
    assert isinstance(executor.timeline.steer, Steering)
    for child in range(1, t.n_nodes):
        parent = t.node_parent[child]
        traj = executor.timeline.steer.to_rest(
            t.node_state[parent], rt.subgoal_q[t.edge_target[child], :3]
        )
        assert traj is not None
        end = state_at(traj, min(traj.duration, eps))
        assert np.array_equal(end, t.node_state[child]), child


def test_failure_contract_none_online_raise_offline(robot):
    steer = Steering.for_robot(robot)
    bad = np.r_[np.full(3, np.nan), np.zeros(6)]
    assert steer.to_rest(bad, np.zeros(3)) is None  # never raises
    assert steer.to_rest(np.zeros(9), [np.inf, 0.0, 0.0]) is None
    with pytest.raises(NoSolutionError):
        steer.steer(bad, np.zeros(3))
    good = steer.steer(np.zeros(9), np.array([0.3, -0.2, 0.1]))
    np.testing.assert_allclose(state_at(good, good.duration)[:3], [0.3, -0.2, 0.1], atol=1e-8)


def test_for_robot_scales_the_limits(robot):
    slow = Steering.for_robot(robot, scale=0.5)
    np.testing.assert_array_equal(slow.v_max, robot.v_max[:3] * 0.5)
    np.testing.assert_array_equal(slow.j_max, robot.j_max[:3] * 0.5)
    fast = Steering.for_robot(robot).to_rest(np.zeros(9), np.array([0.5, 0.0, 0.0]))
    assert slow.to_rest(np.zeros(9), np.array([0.5, 0.0, 0.0])).duration > fast.duration
