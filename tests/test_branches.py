"""Compiled branches as options of the tree planner (thinkfast.decide.branches, choice, executor).

On the session's small compiled tree (real Ruckig edges, real shield paths from the tree file):
continuations are the stored edges end to end, a branch's value agrees with a Monte Carlo of the
moving-shield model, the chooser takes a branch when only its sweep covers a crossing whose point
moves across two goals with its time, and the executor follows the chosen edge and the child
edge chosen at its end.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from path_mc import model_block

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import EXECUTING, Executor
from thinkfast.control.planners.base import follow
from thinkfast.control.segments import EDGE, STEER, hold
from thinkfast.decide.branches import BranchTable, continuation_paths
from thinkfast.decide.choice import BRANCH, DIRECT, BranchPoint, Chooser
from thinkfast.decide.path_value import block_probability
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.tree.file import load_tree

CFG = RunConfig()
ON = dataclasses.replace(CFG, choice=dataclasses.replace(CFG.choice, branches=True))
APPROACH = np.array([-12.0, 0.0, 0.0])  # m/s


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


@pytest.fixture(scope="module")
def chooser(rtree, robot):
    ex = Executor(rtree, robot, ON, "tree")
    return ex.planner.chooser


@pytest.fixture(scope="module")
def table(rtree, chooser):
    return BranchTable(rtree.compiled, chooser.geom, per_goal=0)


def sweep_belief(path: np.ndarray, dt: float, k: int, t_start: float, sd_t: float, sig_a=0.01):
    """A crossing whose point moves with its time as the shield ``path`` does at sample k: mean
    at the shield's (y, z) there at tau = t_start + k dt, slope in tau the shield's velocity."""
    vel = (path[k + 1, 1:] - path[k, 1:]) / dt
    mean = np.r_[path[k, 1:], t_start + k * dt]
    cov = np.zeros((3, 3))
    cov[:2, :2] = sig_a**2 * np.eye(2) + sd_t**2 * np.outer(vel, vel)
    cov[:2, 2] = cov[2, :2] = sd_t**2 * vel
    cov[2, 2] = sd_t**2
    return mean, cov


def test_continuations_are_the_stored_edges_end_to_end_under_each_child(rtree, table):
    t = rtree.compiled
    steps = t.edge_shield.shape[1] - 1
    deep = np.flatnonzero(t.node_depth[t.term_node] == 2)
    row = int(deep[len(deep) // 2])
    node = int(t.term_node[row])
    path = continuation_paths(t, np.array([row]))[0]
    parent = int(t.node_parent[node])
    assert np.array_equal(path[: steps + 1], t.edge_shield[parent])
    assert np.array_equal(path[steps : 2 * steps + 1], t.edge_shield[node])
    s = t.term_shield.shape[1]
    assert np.array_equal(path[2 * steps : 2 * steps + s], t.term_shield[row])
    assert np.array_equal(path[-1], t.term_shield[row, -1])
    # consecutive stored edges meet: the shield path is continuous where they join
    assert np.allclose(t.edge_shield[parent, -1], t.edge_shield[node, 0], atol=1e-12)
    # every continuation below the root is under exactly one child, its depth-1 ancestor
    member, child = table.through(0)
    assert len(member) == len(table.rows) == int(np.count_nonzero(t.term_node > 0))
    first = t.term_node[table.rows[member]]
    first = np.where(t.node_depth[first] == 2, t.node_parent[first], first)
    assert np.array_equal(child, first)
    # below a depth-1 node: its own children only
    m1, c1 = table.through(parent)
    assert np.all(t.node_parent[c1] == parent) and row in table.rows[m1].tolist()


def _scenario(rtree, table):
    """The continuation that leaves home for the sub-goal at (-0.6, 1.45) and, from the first
    node, swings to the goal at (0.15, 0.85): it sweeps across the plane at 1.6 m/s 0.52 s in."""
    t = rtree.compiled
    sub_yz = t.goal_yz[t.subgoal_goal[t.edge_target]]
    member, child = table.through(0)
    rows = table.rows[member]
    node = t.term_node[rows]
    pick = np.flatnonzero(
        (t.node_depth[node] == 1)
        & np.all(np.abs(sub_yz[node] - [-0.6, 1.45]) < 1e-6, axis=1)
        & np.all(np.abs(t.goal_yz[t.term_goal[rows]] - [0.15, 0.85]) < 1e-6, axis=1)
    )
    assert len(pick) == 1
    i = int(pick[0])
    return int(member[i]), int(child[i]), continuation_paths(t, rows[[i]])[0]


def test_a_branch_value_is_its_best_continuation_and_agrees_with_monte_carlo(rtree, table):
    t = rtree.compiled
    m, c, path = _scenario(rtree, table)
    rng = np.random.default_rng(12)
    cases = [
        sweep_belief(path, table.dt, 26, 0.04, 0.1),
        sweep_belief(path, table.dt, 20, 0.1, 0.03),
    ]
    for mean, cov in cases:
        near = np.argsort(np.linalg.norm(t.goal_yz - mean[:2], axis=1))[:3]
        bv = table.values(0, near, mean, cov, APPROACH, 0.04)
        member, child = table.through(0)
        mine = member[(child == c) & np.isin(table.goal[member], near)]
        one = block_probability(table.packed, mean, cov, table.geom, APPROACH, 0.04, index=mine)
        value = float(bv.value[bv.child == c][0])
        assert value == pytest.approx(one.max(), abs=1e-12)  # the best continuation through c
        paths = continuation_paths(t, table.rows[mine])
        grid = np.arange(paths.shape[1]) * table.dt
        mc = [
            model_block(grid, p, mean, cov, table.geom, APPROACH, 0.04, 200_000, rng) for p in paths
        ]
        assert np.max(np.abs(np.array(mc) - one)) < 0.005, (mc, one)
        assert abs(max(mc) - value) < 0.005


def test_the_chooser_takes_a_branch_when_only_its_sweep_covers_both_goals(rtree, table, chooser):
    """The crossing point runs with its time from one goal to the next (the ball's time and
    height are correlated): resting at either goal covers one end of it, the compiled branch
    that sweeps across at the right time covers both."""
    t = rtree.compiled
    m, c, path = _scenario(rtree, table)
    mean, cov = sweep_belief(path, table.dt, 26, 0.04, 0.1)
    ends = [mean[:2] + s * np.sqrt(cov[2, 2]) * cov[:2, 2] / cov[2, 2] for s in (-1.0, 1.0)]
    goals = [rtree.nearest_goal(e) for e in ends]
    assert goals[0] != goals[1]  # two goals, 1 sigma either side
    home = np.r_[t.node_state[0, :3], np.zeros(6)]
    many = dataclasses.replace(chooser.cfg, candidates=24)  # direct moves to 24 goals around
    chooser = Chooser(t.goal_q, t.goal_yz, chooser.sampler.robot, rtree.plane_x,
                      rtree.ball_radius, chooser.steer, many)  # fmt: skip
    best, options = chooser.choose(
        mean, cov, APPROACH, 0.0, 0.0, 0.04, home, hold(home, 0.0), BranchPoint(0, 0.0), table
    )
    direct = {o.goal: o.value for o in options if o.kind == DIRECT}
    assert set(goals) <= set(direct)
    assert best.kind == BRANCH and best.node == c
    assert best.value > max(direct.values()) + 0.05, (best.value, direct)
    assert best.value > options[0].value + 0.05  # staying home (the shield is near) is worse
    # without the branches the same belief gets less: every other option leaves an end open
    alone, _ = chooser.choose(mean, cov, APPROACH, 0.0, 0.0, 0.04, home, hold(home, 0.0))
    assert alone.kind != BRANCH and alone.value < best.value - 0.05


def _executor(rtree, robot):
    ex = Executor(rtree, robot, ON, "tree")
    ex.start_from(robot.home, 0.0)
    ex.mode = EXECUTING
    ex.gate.t_last_det = 10.0  # the ball is still seen and its crossing ahead: no return
    ex.episode.t_cross = 10.0
    return ex


def test_the_executor_follows_a_chosen_edge_and_the_child_chosen_for_its_end(rtree, robot):
    t = rtree.compiled
    ex = _executor(rtree, robot)
    eps = rtree.eps
    at = ex.planner.branch_point(0.2)
    assert at == BranchPoint(0, 0.2)  # home at rest: the root
    child = int(t.child_start[0] + 1)
    follow(ex.timeline, ex.episode, ex.planner.take_branch(child, at, 0.2))
    assert ex.segment.kind == EDGE and ex.segment.ref == child and ex.episode.path == [child]
    grand = int(t.child_start[child] + t.child_count[child] - 1)
    at = ex.planner.branch_point(0.25)
    assert at == BranchPoint(child, 0.2 + eps)  # the end of the edge in progress
    follow(ex.timeline, ex.episode, ex.planner.take_branch(grand, at, 0.25))
    assert ex.timeline.pending == (grand, 0.2 + eps) and ex.segment.ref == child  # not yet
    states, times = [], 0.2 + np.arange(0, 2 * eps + 1e-9, 0.004)
    for tick in times:
        q, qd = ex.setpoint(float(tick))
        states.append(ex.segment.state(float(tick)))
    states = np.array(states)
    # the commanded joints pass through both compiled nodes' states on time (to Ruckig's 1e-9)
    i1, i2 = int(round(eps / 0.004)), int(round(2 * eps / 0.004))
    assert np.max(np.abs(states[i1] - t.node_state[child])) < 1e-9
    assert np.max(np.abs(states[i2] - t.node_state[grand])) < 1e-9
    assert ex.segment.kind == EDGE and ex.segment.ref == grand and ex.timeline.pending is None
    assert ex.episode.path == [child, grand]
    jump = np.abs(np.diff(states[:, 3:6], axis=0)).max()  # velocity continuous at the switch
    assert jump < 0.004 * robot.a_max[:3].max() * 1.01
    # past the node of a depth-2 tree's leaf no edge can start: off the tree
    assert ex.planner.branch_point(0.2 + 2 * eps + 0.01) is None


def test_no_branch_point_off_the_tree_and_a_replaced_edge_drops_its_pending_child(rtree, robot):
    t = rtree.compiled
    ex = _executor(rtree, robot)
    child = int(t.child_start[0])
    follow(
        ex.timeline, ex.episode, ex.planner.take_branch(child, ex.planner.branch_point(0.0), 0.0)
    )
    at = ex.planner.branch_point(0.05)
    grand = int(t.child_start[child])
    follow(ex.timeline, ex.episode, ex.planner.take_branch(grand, at, 0.05))
    assert ex.timeline.pending is not None
    # a direct move replaces the edge: its switch is void
    follow(ex.timeline, ex.episode, ex.planner.steer(3, 0.06))
    assert ex.segment.kind == STEER and ex.timeline.pending is None
    assert ex.planner.branch_point(0.07) is None  # moving off the tree: no compiled edge can start
    ex.resync(np.r_[ex.segment.state(0.08)[:3], robot.home[3:]], np.zeros(6), np.zeros(6), 0.08)
    assert ex.planner.branch_point(0.09) is None
    off = Executor(rtree, robot, CFG, "tree")
    off = off.planner  # switched off by default
    assert off.branches is None and off.branch_point(0.0) is None
