"""Action tree growth: structure, exact chaining of primitives, limits, collisions, determinism."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from tests.conftest import ROBOT_TOML, small_tree_config
from thinkfast.compile.build import compile_tree
from thinkfast.compile.config import load_compile_config
from thinkfast.robot.steering import Steering, state_at
from thinkfast.tree.action_tree import EDGE_CUT, EDGE_REACHED
from thinkfast.tree.file import tree_fingerprint


def small_config(tmp_path, robot=ROBOT_TOML):
    return load_compile_config(small_tree_config(tmp_path, robot, radius=0.25))


@pytest.fixture(scope="module")
def small_trees(tmp_path_factory):
    cfg = small_config(tmp_path_factory.mktemp("tree"))
    return compile_tree(cfg, jobs=1), compile_tree(cfg, jobs=2), cfg


@pytest.fixture(scope="module")
def steer(robot):
    return Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])


def test_jobs_1_and_2_give_identical_datasets(small_trees):
    a, b, _ = small_trees
    assert tree_fingerprint(a) == tree_fingerprint(b)
    for name, arr in a.arrays().items():
        assert np.array_equal(arr, b.arrays()[name]), name


def test_layout_is_breadth_first_with_contiguous_children(small_trees):
    t = small_trees[0]
    assert t.node_parent[0] == -1 and t.node_depth[0] == 0
    assert np.all(np.diff(t.node_depth) >= 0)
    for i in range(t.n_nodes):
        kids = np.arange(t.child_start[i], t.child_start[i] + t.child_count[i])
        assert np.all(t.node_parent[kids] == i)
        assert np.all(t.node_depth[kids] == t.node_depth[i] + 1)
        terms = np.arange(t.term_start[i], t.term_start[i] + t.term_count[i])
        assert np.all(t.term_node[terms] == i)
    assert t.child_count.sum() == t.n_nodes - 1 and t.term_count.sum() == t.n_terminals


def test_child_starts_exactly_at_parent_state_and_time_to_come_adds_up(small_trees, steer):
    t, _, cfg = small_trees
    eps = cfg.config.tree.eps
    for i in range(1, t.n_nodes):
        p = t.node_parent[i]
        traj = steer.steer(t.node_state[p], t.goal_q[t.subgoal_goal[t.edge_target[i]], :3])
        assert np.array_equal(state_at(traj, 0.0), t.node_state[p])  # starts at the parent
        t_move = min(traj.duration, eps)
        assert np.max(np.abs(state_at(traj, t_move) - t.node_state[i])) < 1e-12
        assert t.edge_kind[i] == (EDGE_REACHED if traj.duration <= eps else EDGE_CUT)
        assert t.node_ttc[i] == t.node_ttc[p] + t.edge_duration[i]  # exactly
        assert t.edge_duration[i] == eps


def test_terminals_end_at_their_goal_at_rest(small_trees, steer):
    t = small_trees[0]
    assert np.array_equal(t.term_arrival, t.node_ttc[t.term_node] + t.term_duration)
    for k in range(0, t.n_terminals, 7):
        traj = steer.steer(t.node_state[t.term_node[k]], t.goal_q[t.term_goal[k], :3])
        end = state_at(traj, traj.duration)
        # at the goal at rest to Ruckig's precision (its solver lands within ~1e-8 rad)
        assert np.allclose(end[:3], t.goal_q[t.term_goal[k], :3], atol=1e-7)
        assert np.allclose(end[3:], 0.0, atol=1e-7)
        assert traj.duration == t.term_duration[k]


def test_every_goal_is_covered_and_home_reaches_all(small_trees):
    t = small_trees[0]
    assert set(t.term_goal.tolist()) == set(range(len(t.goal_q)))
    root_goals = t.term_goal[t.term_start[0] : t.term_start[0] + t.term_count[0]]
    assert sorted(root_goals.tolist()) == list(range(len(t.goal_q)))


def test_states_stay_inside_limits(small_trees, robot):
    t = small_trees[0]
    margin = 0.01
    assert np.all(t.node_q >= robot.q_lower + margin - 1e-12)
    assert np.all(t.node_q <= robot.q_upper - margin + 1e-12)
    assert np.all(np.abs(t.node_state[:, 3:6]) <= robot.v_max[:3] + 1e-9)
    assert np.all(np.abs(t.node_state[:, 6:9]) <= robot.a_max[:3] + 1e-9)


def test_an_obstacle_in_the_cell_discards_colliding_primitives(tmp_path, robot, steer):
    """A pillar between home and the left goals: primitives through it are dropped, none kept
    collides when re-checked densely with the scalar fcl checker."""
    from thinkfast.robot.collision import CollisionChecker
    from thinkfast.robot.model import load_robot
    from thinkfast.robot.wrist import CoplanarWrist

    rdir = tmp_path / "robot"
    shutil.copytree(ROBOT_TOML.parent, rdir)
    with open(rdir / "robot.toml", "a") as f:
        f.write(
            '\n[[cell]]\nname = "pillar"\nshape = "box"\nsize = [0.1, 0.1, 3.0]\n'
            "xyz = [0.75, 0.45, 1.0]\n"
        )
    cfg = small_config(tmp_path, robot=rdir / "robot.toml")
    tree = compile_tree(cfg, jobs=1)
    assert "collision" in tree.meta["tree_discards"] + tree.meta["terminal_discards"]
    pillar_robot = load_robot(rdir / "robot.toml")
    checker = CollisionChecker(pillar_robot)
    wrist = CoplanarWrist(pillar_robot)
    for k in range(0, tree.n_terminals, 3):
        node = tree.term_node[k]
        traj = steer.steer(tree.node_state[node], tree.goal_q[tree.term_goal[k], :3])
        ts = np.linspace(0, traj.duration, 200)
        q123 = np.array([traj.at_time(x)[0] for x in ts])
        q = np.column_stack([q123, wrist.solve(q123, tree.node_q[node, 3:])])
        assert not any(checker.in_collision(x) for x in q)


def test_shield_paths_sampled_by_the_workers_equal_sampling_them_again(small_trees, robot):
    """The workers sample each edge's shield path with the trajectory they checked; the tree's
    paths equal, bit for bit, the ones ``edge_shield_paths`` samples again from the stored
    states (as ``verify`` does), terminal edges held at their goal up to the longest."""
    from thinkfast.compile.shield import edge_shield_paths, sample_spacing

    t, _, cfg = small_trees
    tc = cfg.config.tree
    edge, term = edge_shield_paths(
        robot, t.node_parent, t.node_state, t.edge_target, t.term_node, t.term_goal,
        t.term_duration, t.goal_q, t.subgoal_goal, tc.eps, sample_spacing(tc.eps, tc.shield_dt),
    )  # fmt: skip
    assert edge.shape == t.edge_shield.shape and term.shape == t.term_shield.shape
    assert np.array_equal(edge, t.edge_shield)
    assert np.array_equal(term, t.term_shield)
