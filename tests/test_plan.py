"""A plan as data: its cubic pieces are Ruckig's trajectory, and the follower's setpoints are the
executor's along a whole throw."""

import dataclasses

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import Executor
from thinkfast.control.intake import Intake
from thinkfast.control.plan import Pieces, PlanFollower, decode_plan, executor_plan
from thinkfast.control.planners.base import follow
from thinkfast.robot.steering import Steering
from thinkfast.sim.camera import CameraModelConfig, detection_payload, observe
from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.lockstep import DT, LEAD, World
from thinkfast.sim.throws import ThrowConfig, make_throw, plane_crossing
from thinkfast.tree.file import load_tree

CFG = RunConfig()


def test_pieces_give_ruckigs_states_for_random_moves_with_brake_phases(robot):
    rng = np.random.default_rng(7)
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    braked = 0
    for _ in range(200):
        v = rng.uniform(-1.3, 1.3, 3) * robot.v_max[:3]  # some beyond the limit: a brake phase
        a = rng.uniform(-1, 1, 3) * robot.a_max[:3]
        state = np.r_[rng.uniform(-1, 1, 3), v, a]
        traj = steer.to_rest(state, rng.uniform(-1, 1, 3))
        assert traj is not None
        braked += any(p.brake.duration > 0 for p in traj.profiles[0])
        pieces = Pieces(*Pieces.of(traj), traj.duration)
        for s in np.r_[np.linspace(0.0, traj.duration, 97), traj.duration + 0.1]:
            want = np.array(traj.at_time(min(s, traj.duration)))
            got = np.array(pieces.at_time(min(s, traj.duration)))
            assert np.allclose(got, want, rtol=1e-12, atol=1e-11), (s, got - want)
    assert braked > 10  # the brake pre-trajectories were exercised


@pytest.fixture(scope="module")
def world(small_tree_015, robot):
    return World(load_tree(small_tree_015), robot, CFG, ServoConfig(), CameraModelConfig())


BRANCHES = dataclasses.replace(CFG, choice=dataclasses.replace(CFG.choice, branches=True))


@pytest.mark.parametrize("planner, cfg", [("tree", CFG), ("naive", CFG), ("tree", BRANCHES)],
                         ids=["tree", "naive", "tree-branches"])  # fmt: skip
def test_the_follower_of_each_published_plan_commands_what_the_executor_does(world, planner, cfg):
    """A throw in lockstep: before every tick the executor's plan (after the detections) goes
    through the plan vector to a follower; its setpoint equals the executor's at every tick but
    those where the executor starts a segment it could not announce (the end of the throw, the
    end of the way home), and those are continuous."""
    mid = world.tree.goal_yz.mean(axis=0) + np.array([0.15, 0.1])
    th = make_throw(ThrowConfig(), np.array([7.6, 0.2, 1.4]), tuple(mid), 0.75, 0.5, "blind")
    t_rel = LEAD + th.t_release
    dets = observe(th, world.camera, CFG.camera, np.random.default_rng(3), t_rel)
    ex = Executor(world.tree, world.robot, cfg, planner)
    ex.start_from(world.robot.home, 0.0)
    follower = PlanFollower(world.robot, CFG)
    follower.start_from(world.robot.home, 0.0)
    follower.epoch = 0  # the executor made the same start
    intake = Intake(CFG.camera, CFG.detections)
    k, t, plan_id, same, unannounced = 0, 0.0, 0, 0, 0
    t_end = t_rel + plane_crossing(th).t + 3.0
    while t < t_end:
        while k < len(dets) and dets[k].delivery_time <= t:
            acc = intake.take(detection_payload(dets[k]), None)
            k += 1
            if acc is not None:
                ex.on_detection(t, acc.stamp, acc.position, acc.camera)
        plan_id += 1
        plan = decode_plan(executor_plan(ex, plan_id, 0))
        assert follower.adopt(plan)
        seg = ex.timeline.segment
        got = follower.setpoint(t)
        want = ex.setpoint(t)
        new = ex.timeline.segment
        if new is not seg and all(new.t0 != s.t0 for s in plan.segments[1:]):
            unannounced += 1
            assert np.allclose(got[0], want[0], atol=0.02)
            follower.wrist.reset(want[0][3:], t, want[1][3:], ex.wrist.state[6:])
        else:
            assert np.allclose(got[0], want[0], rtol=0, atol=1e-9), t
            assert np.allclose(got[1], want[1], rtol=0, atol=1e-8), t
            same += 1
        t += DT
    assert ex.episodes == 1 and same > 500
    assert unannounced <= 3


def test_the_queued_child_edge_is_announced_as_the_tree_planner_will_start_it(world):
    from thinkfast.control.planners.base import EpisodeLog

    ex = Executor(world.tree, world.robot, BRANCHES, "tree")
    ex.start_from(world.robot.home, 0.0)
    parent = world.tree.compiled.node_parent
    child = next(c for c in range(1, len(parent)) if parent[c] == 0 and (parent == c).any())
    grandchild = int(np.flatnonzero(parent == child)[0])
    ep = EpisodeLog()
    follow(ex.timeline, ep, ex.planner.start_edge(child, 0.0))
    t_switch = world.tree.eps
    ex.timeline.pending = (grandchild, t_switch)
    announced = ex.planner.pending_segment()
    plan = decode_plan(executor_plan(ex, 1, 0))
    assert len(plan.segments) == 2 and plan.segments[1].t0 == t_switch
    follow(ex.timeline, ep, ex.planner.advance(t_switch, ep))
    started = ex.timeline.segment
    assert started.ref == grandchild == announced.ref and started.t0 == announced.t0
    for s in np.linspace(0.0, started.duration, 25):
        assert np.allclose(started.state(t_switch + s), plan.segments[1].state(t_switch + s),
                           rtol=0, atol=1e-11)  # fmt: skip
