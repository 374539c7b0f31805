"""One Ruckig wrapper: the runtime's edges are the compiler's, bit for bit; one failure contract."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.errors import NoSolutionError
from thinkfast.robot.steering import Steering, feasible_acceleration, peaks, state_at


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


def _sampled(traj, dt: float) -> tuple[np.ndarray, np.ndarray]:
    times = np.r_[np.arange(0.0, traj.duration, dt), traj.duration]
    x = np.array([state_at(traj, t) for t in times])
    n = traj.degrees_of_freedom
    return np.abs(x[:, n : 2 * n]).max(axis=0), np.abs(x[:, 2 * n :]).max(axis=0)


def test_peaks_are_the_largest_speed_and_acceleration_along_the_move(robot):
    """Exact from the profiles, brakes included: never below a dense sampling, and above it by
    no more than the sampling step can miss."""
    steer = Steering.for_robot(robot, scale=0.2)
    rng = np.random.default_rng(5)
    dt = 5e-4
    braked = 0
    for _ in range(40):
        v0 = rng.uniform(-1.5, 1.5, 3) * steer.v_max  # some start above the limits
        a0 = rng.uniform(-1.5, 1.5, 3) * steer.a_max
        traj = steer.to_rest(np.r_[rng.uniform(-1, 1, 3), v0, a0], rng.uniform(-1, 1, 3))
        assert traj is not None
        v_peak, a_peak = peaks(traj)
        v_seen, a_seen = _sampled(traj, dt)
        assert np.all(v_peak >= v_seen - 1e-12) and np.all(a_peak >= a_seen - 1e-12)
        assert np.all(v_peak - v_seen <= steer.a_max * dt) and np.all(
            a_peak - a_seen <= steer.j_max * dt
        )
        braked += bool(np.any(v_peak > steer.v_max * (1 + 1e-9)))
    assert braked > 5  # brakes that pass the limits were among them


def test_a_feasible_acceleration_keeps_the_plan_within_the_velocity_limit(robot):
    steer = Steering.for_robot(robot, scale=0.2)
    v0 = 0.97 * steer.v_max * np.array([1.0, -1.0, 1.0])
    a0 = 0.8 * steer.a_max * np.sign(v0)  # speeding up near the limit: no ramp down in time
    target = np.sign(v0) * 2.0
    raw = peaks(steer.to_rest(np.r_[np.zeros(3), v0, a0], target))[0]
    assert np.all(raw > steer.v_max * 1.001)
    a = feasible_acceleration(v0, a0, steer.v_max, steer.a_max, steer.j_max)
    assert np.all(np.abs(a) < np.abs(a0)) and np.all(np.sign(a) == np.sign(a0))
    fixed = peaks(steer.to_rest(np.r_[np.zeros(3), v0, a], target))[0]
    assert np.all(fixed <= steer.v_max * (1 + 1e-9))
    # an acceleration a plan can hold is left alone: slowing down, or far from the limit
    for v, acc in ((v0, -a0), (0.1 * v0, a0)):
        np.testing.assert_array_equal(
            feasible_acceleration(v, acc, steer.v_max, steer.a_max, steer.j_max), acc
        )


def test_moves_from_one_state_to_many_targets_are_the_single_moves_bit_for_bit(robot):
    steer = Steering.for_robot(robot)
    rng = np.random.default_rng(11)
    state = np.r_[rng.uniform(-1, 1, 3), rng.uniform(-0.5, 0.5, 3), rng.uniform(-1, 1, 3)]
    targets = rng.uniform(-1, 1, (5, 3))
    targets[2] = np.inf  # a failure in the middle leaves the others alone
    each = steer.to_rest_each(state, targets)
    assert each[2] is None
    for target, traj in zip(targets, each, strict=True):
        one = steer.to_rest(state, target)
        if one is None:
            assert traj is None
            continue
        assert traj.duration == one.duration
        for t in np.linspace(0.0, one.duration, 17):
            assert traj.at_time(t) == one.at_time(t)
