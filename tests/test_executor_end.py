"""When a throw ends: not when the camera loses the ball while its crossing is still ahead."""

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import EXECUTING, IDLE, RETURNING, Executor
from thinkfast.control.intake import Intake
from thinkfast.control.link import Feedback
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


# ------------------------------------------------------ feints the launch detector confirmed
# (s<seed>-f<j>: feint j of `bench/hedge.py run --throws 0 --feints 100 --seed <seed>`, camera
# noise seed throw_seed(seed, j)); on the default tree each moved the shield 1.11-1.15 m and was
# not home 2 s after its ball stopped (docs/RESULTS.md, "Feints, held balls")
CONFIRMED_FEINTS = [(2, 54), (3, 16), (3, 83)]


def _fly_feint(world, seed: int, j: int):
    """Lockstep (thinkfast/sim/lockstep.py's loop) over feint ``j`` of ``seed`` with the tree
    planner until FEINT_WINDOW after its ball stopped. Returns the control core, the time the
    ball stopped and the references the controller received."""
    from thinkfast.sim.bench import throw_seed
    from thinkfast.sim.camera import observe_cameras
    from thinkfast.sim.controller import SimController
    from thinkfast.sim.judge import FEINT_WINDOW
    from thinkfast.sim.throws import sample_throws

    th = sample_throws(ThrowConfig(), 0, seed, j + 1)[j]  # a feint depends on (config, seed, j)
    assert th.kind == "feint" and th.id == f"s{seed}-f{j}"
    t_stop = LEAD + th.t_release
    dets = observe_cameras(th, world.cameras, throw_seed(seed, j), t_stop)
    sim = SimController(world.servo, q0=world.robot.home)
    core = world.parts.core(world.parts.executor("tree"))
    k, t = 0, 0.0
    while t <= t_stop + FEINT_WINDOW + 0.2:
        while k < len(dets) and dets[k].delivery_time <= t:
            core.on_detection(detection_payload(dets[k]), None, t)
            k += 1
        reply = core.on_feedback(Feedback(round(t * 1000.0), sim.q), t)
        if reply is not None:
            sim.command(reply.q, reply.qd, t)
        sim.step(DT)
        t += DT
    return core, t_stop, sim


@pytest.mark.parametrize(("seed", "j"), CONFIRMED_FEINTS, ids=lambda x: str(x))
def test_a_feint_taken_for_a_throw_is_retracted_and_home_within_2_s(world, seed, j):
    """The launch detector confirms these feints (the arm leaves home for a throw) and the ball
    then rests in the hand: its predicted crossing keeps receding, and before the retraction
    the throw never ended while the ball was seen. The flight watch retracts it: the arm stops,
    goes home within the limits (no supervisor intervention, no velocity step beyond the
    acceleration limit) and is home, at rest, within 2 s of the ball stopping."""
    from thinkfast.sim.judge import FEINT_WINDOW, judge_feint

    core, t_stop, sim = _fly_feint(world, seed, j)
    ex, robot = core.ex, world.robot
    ep = ex.last_episode if ex.last_episode is not None else ex.episode
    assert not np.isnan(ep.t_start)  # confirmed and left home: the case under test
    hist = sim.history()
    f = judge_feint(hist.t, hist.q, world.kin, robot.home, t_stop, FEINT_WINDOW)
    assert f.displacement > 0.1  # it did go out
    assert f.home_again and f.home_after <= FEINT_WINDOW, f
    assert ep.end == "retracted" and ex.throw_end == "retracted"
    assert core.sup.intervened == 0, {k: v for k, v in core.sup.counts.items() if v}
    wire = sim.commands()
    cycles = np.round(np.diff(wire.t) / DT)[:, None]
    assert np.all(np.abs(wire.qd) <= robot.v_max + 1e-9)
    assert np.all(np.abs(np.diff(wire.qd, axis=0)) <= robot.a_max * DT * cycles + 1e-9)
