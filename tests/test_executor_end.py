"""When a throw ends: not when the camera loses the ball while its crossing is still ahead."""

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import EXECUTING, IDLE, RETURNING, Executor
from thinkfast.control.intake import Intake
from thinkfast.sim.camera import CameraModelConfig, detection_payload, observe
from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.lockstep import DT, LEAD, World
from thinkfast.sim.throws import ThrowConfig, make_throw, plane_crossing
from thinkfast.tree.file import load_tree

CFG = RunConfig()


@pytest.fixture(scope="module")
def world(small_tree_015, robot):
    return World(load_tree(small_tree_015), robot, CFG, ServoConfig(), CameraModelConfig())


def _fly(world, seen_for: float, planner: str = "naive"):
    """A 0.75 s throw at the middle of the goal grid whose detections stop ``seen_for`` [s]
    after the release. Returns (release time, true crossing time, modes per tick)."""
    mid = world.tree.goal_yz.mean(axis=0)
    th = make_throw(ThrowConfig(), np.array([7.6, 0.2, 1.4]), tuple(mid), 0.75, 0.5, "blind")
    t_rel = LEAD + th.t_release
    dets = observe(th, world.camera, CFG.camera, np.random.default_rng(3), t_rel)
    dets = [d for d in dets if d.capture_stamp < t_rel + seen_for]
    t_cross = t_rel + plane_crossing(th).t
    ex = Executor(world.tree, world.robot, CFG, planner)
    ex.start_from(world.robot.home, 0.0)
    intake = Intake(CFG.camera, CFG.detections)
    k, t, modes = 0, 0.0, []
    while t < t_cross + 2.0:
        while k < len(dets) and dets[k].delivery_time <= t:
            acc = intake.take(detection_payload(dets[k]), None)
            k += 1
            if acc is not None:
                ex.on_detection(t, acc.stamp, acc.position)
        ex.setpoint(t)
        modes.append((t, ex.mode))
        t += DT
    return t_rel, t_cross, modes


def _first(modes, mode, after=0.0):
    return next(t for t, m in modes if m == mode and t >= after)


@pytest.mark.parametrize("planner", ["naive", "tree"])
def test_a_ball_lost_from_view_before_the_plane_is_still_awaited_at_its_crossing(world, planner):
    """Detections stop 0.35 s after the release, 0.4 s before the crossing: longer than the
    detection timeout. The arm holds its plan until the predicted crossing has passed."""
    t_rel, t_cross, modes = _fly(world, seen_for=0.35, planner=planner)
    start = _first(modes, EXECUTING)
    ret = _first(modes, RETURNING, after=start)
    th = CFG.throw
    assert t_rel + 0.35 + th.detection_timeout < t_cross  # the timeout alone would end it early
    assert ret > t_cross + CFG.execution.controller_lag  # it waited for the ball
    assert ret < t_cross + CFG.execution.controller_lag + th.after_crossing + 0.05
    assert modes[-1][1] in (IDLE, RETURNING)


def test_a_ball_seen_to_the_plane_ends_the_throw_after_its_crossing(world):
    t_rel, t_cross, modes = _fly(world, seen_for=10.0)
    ret = _first(modes, RETURNING, after=_first(modes, EXECUTING))
    assert t_cross < ret < t_cross + CFG.execution.controller_lag + CFG.throw.after_crossing + 0.05


def test_a_throw_blind_for_max_blind_ends_even_with_its_crossing_ahead(world):
    """A crossing predicted far ahead (a belief gone wrong) does not keep the arm out forever."""
    ex = Executor(world.tree, world.robot, CFG, "naive")
    ex.start_from(world.robot.home, 0.0)
    ex.mode, ex.gate.t_last_det = EXECUTING, 1.0
    ex.episode.t_cross = 10.0
    ex.setpoint(1.0 + CFG.throw.detection_timeout + 0.1)
    assert ex.mode == EXECUTING
    ex.setpoint(1.0 + CFG.throw.max_blind + 0.06)
    assert ex.mode in (RETURNING, IDLE)  # the arm was at home: the return ends at once


@pytest.mark.parametrize("away", [0.0, 0.3])
def test_a_return_whose_way_home_was_replaced_by_a_hold_still_ends_at_home(world, away):
    """A resync while returning can leave a plain hold (Ruckig cannot plan a move of zero
    length, or failed): the executor used to wait in ``returning`` for good, ignoring every
    later throw (seen in a 10-minute soak: 27 of 200 throws executed). It plans the way home
    again and becomes ready."""
    from thinkfast.control.segments import hold

    robot = world.robot
    ex = Executor(world.tree, robot, CFG, "naive")
    ex.start_from(robot.home, 0.0)
    q = np.array(robot.home[:3], dtype=float) + [away, -away / 2, away / 3]
    ex.mode = RETURNING
    ex.timeline.segment = hold(np.r_[q, np.zeros(6)], 1.0)
    t = 1.0
    while ex.mode == RETURNING and t < 8.0:
        q_cmd, _ = ex.setpoint(t)
        t += DT
    assert ex.mode == IDLE
    np.testing.assert_allclose(q_cmd[:3], robot.home[:3], atol=1e-6)
