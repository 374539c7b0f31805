"""The hedge stage, clock-free: the executor driven by scripted detections and 4 ms setpoint
ticks (tests/test_executor_modes.py's driver), and feints flown in lockstep.

Claims: before the launch is confirmed the shield stays within ``[hedge] bound`` of home; a
hedge the launch detector never confirms ends and the arm is home again; at the hand-over to the
commit stage the commanded joints are continuous in position, velocity and acceleration;
feints leave the shield within the bound and home again within 2 s."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tests.test_executor_modes import CFG, DT, END, HELD, RELEASE, THROW, Run, feed
from thinkfast.control.executor import EXECUTING, IDLE, Executor
from thinkfast.control.hedge import COMMIT
from thinkfast.control.link import Feedback
from thinkfast.control.outcome import state_of
from thinkfast.daemon.status_text import episode_end, episode_text
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.tree.file import load_tree


def _cfg(mode: str, **launch) -> object:
    cfg = dataclasses.replace(CFG, hedge=dataclasses.replace(CFG.hedge, mode=mode))
    if launch:  # a launch gate that never confirms: the throw gate needs 100 m/s
        cfg = dataclasses.replace(
            cfg,
            launch=dataclasses.replace(cfg.launch, **launch),
            throw=dataclasses.replace(cfg.throw, min_approach_speed=100.0),
        )
    return cfg


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


class Trace:
    """Every tick's commanded joint 1-3 state (p, v, a) and shield displacement from home."""

    def __init__(self, ex: Executor, robot):
        self.ex, self.sampler = ex, ShieldSampler(robot)
        self.home = self.sampler.centres(np.asarray(robot.home[:3], dtype=float))
        self.t, self.states, self.stages = [], [], []

    def run(self, ball, until: float, seed: int = 7) -> Run:
        run = Run(self.ex, seed)
        while run.t < until - 1e-9:
            feed(ball, run.t + DT)(run)
            self.t.append(run.t)
            self.states.append(self.ex.segment.state(run.t).copy())
            self.stages.append(self.ex.stage)
        return run

    def displacement(self) -> np.ndarray:
        q = np.array(self.states)[:, :3]
        return np.linalg.norm(self.sampler.centres(q) - self.home, axis=-1)


@pytest.mark.parametrize("mode", ["mean", "tree"])
def test_an_unconfirmed_hedge_stays_within_the_bound_and_ends_at_home(mode, rtree, robot):
    cfg = _cfg(mode, min_speed=100.0)
    ex = Executor(rtree, robot, cfg, "tree")
    trace = Trace(ex, robot)
    trace.run(THROW, RELEASE + 1.8)  # the ball reaches the plane at 1.7 s; 0.8 s to come home
    disp = trace.displacement()
    assert math.isnan(ex.episode.t_confirmed)
    assert ex.hedges >= 1 and ex.hedge_end in ("timeout", "no_launch", "silence")
    if mode == "mean":  # the throw aims away from home: the mean-goal hedge leaves
        assert disp.max() > 0.02
    assert disp.max() <= cfg.hedge.bound + 1e-9
    assert ex.mode == IDLE and np.allclose(trace.states[-1][:3], robot.home[:3], atol=1e-6)
    assert np.allclose(trace.states[-1][3:], 0.0, atol=1e-9)  # at rest (Ruckig: within 1e-8)


def _edges_cfg(backup: str, **launch):
    cfg = _cfg("tree", **launch)
    return dataclasses.replace(
        cfg,
        hedge=dataclasses.replace(cfg.hedge, terminals=True),
        value=dataclasses.replace(cfg.value, backup=backup),
    )


def test_a_look_ahead_hedge_on_the_trees_edges_stays_within_the_bound(rtree, robot):
    cfg = _edges_cfg("lookahead", min_speed=100.0)
    ex = Executor(rtree, robot, cfg, "tree")
    assert ex.hedge.hedger.foresight is not None
    trace = Trace(ex, robot)
    trace.run(THROW, RELEASE + 1.8)
    assert ex.hedges >= 1 and trace.displacement().max() <= cfg.hedge.bound + 1e-9
    assert ex.mode == IDLE and np.allclose(trace.states[-1][:3], robot.home[:3], atol=1e-6)


def test_with_terminals_the_tree_hedge_heads_for_homes_best_terminal_edge(rtree, robot):
    cfg = _edges_cfg("qmdp")
    h = Executor(rtree, robot, cfg, "tree").hedge.hedger
    mean = np.array([5.8, 0.35, 1.1, -10.0, 0.0, 2.0])  # a ball 5 m out, wide across the plane
    c = rtree.crossing(mean, np.diag([0.1**2] * 3 + [1.0] * 3), cfg.filter.gravity)
    d = rtree.decide(c, 0.0, 0.0, h.lag)
    assert d.backup.term_value[0] >= d.backup.child_value[0]  # a direct move is worth the most
    goal = rtree.compiled.term_goal[rtree.best_terminal(d, 0)]
    q = h.target(c, 0.0, 0.0)
    assert np.array_equal(q, h.truncate(rtree.goal_q[goal, :3]))
    assert h.displacement(q) <= cfg.hedge.bound
    no_terms = dataclasses.replace(cfg, hedge=dataclasses.replace(cfg.hedge, terminals=False))
    h0 = Executor(rtree, robot, no_terms, "tree").hedge.hedger
    child = rtree.best_child(d, 0)
    want = rtree.subgoal_q[rtree.compiled.edge_target[child], :3]
    assert np.array_equal(h0.target(c, 0.0, 0.0), h0.truncate(want))  # today's: a child edge


def test_the_commit_takes_over_from_the_hedge_without_a_jump(rtree, robot):
    cfg = _cfg("mean")
    ex = Executor(rtree, robot, cfg, "tree")
    trace = Trace(ex, robot)
    trace.run(THROW, RELEASE + 0.4)
    ep = ex.episode
    assert ep.t_hedge < ep.t_confirmed  # the hedge began before the confirmation
    assert ex.stage == COMMIT and ex.hedge_end == "confirmed" and ex.mode == EXECUTING
    s = np.array(trace.states)
    t = np.array(trace.t)
    before = trace.displacement()[t < ep.t_confirmed]
    assert before.max() > 0.0 and before.max() <= cfg.hedge.bound + 1e-9
    # every tick, hand-over included: no step larger than the limits allow over one tick
    step = np.abs(np.diff(s, axis=0))
    lim = np.r_[robot.v_max[:3], robot.a_max[:3], robot.j_max[:3]] * DT * 1.01 + 1e-9
    assert np.all(step <= lim), np.argwhere(step > lim)[:5]
    k = int(np.searchsorted(t, ep.t_confirmed))
    assert np.any(s[k - 1, 3:6] != 0.0)  # it was moving when the commit took over


def test_a_held_ball_never_starts_a_hedge(rtree, robot):
    ex = Executor(rtree, robot, _cfg("mean"), "tree")
    trace = Trace(ex, robot)
    trace.run(HELD, 3.0)
    assert ex.hedges == 0 and trace.displacement().max() == 0.0


def test_no_hedge_mode_is_todays_executor(rtree, robot):
    """``mode = none`` commands the same setpoints as an executor that knows no hedge."""
    a = Trace(Executor(rtree, robot, _cfg("none"), "tree"), robot)
    a.run(THROW, RELEASE + 0.5)
    b = Trace(Executor(rtree, robot, _cfg("mean"), "tree"), robot)
    b.ex.hedge = None  # the executor as it was: no hedge stage at all
    b.run(THROW, RELEASE + 0.5)
    assert a.ex.hedge is None
    np.testing.assert_array_equal(np.array(a.states), np.array(b.states))


def test_an_episode_hedged_on_but_never_confirmed_ends_with_its_own_figures(rtree, robot):
    """A throw confirmed and flown, then a ball seen for three flight frames only: a hedge
    begins, the launch is never confirmed, the arm comes home. The end of that episode tells
    of it (not confirmed, one hedge), never the previous throw's figures."""
    ex = Executor(rtree, robot, CFG, "tree")
    run = Run(ex, 7)
    feed(THROW, END + 1.5)(run)
    assert ex.mode == IDLE and ex.episodes == 1 and ex.last_episode.decisions > 0
    release = run.t + 1.0
    glimpse = THROW._replace(release=release, t_seen=release - 0.6, t_lost=release + 0.07)
    feed(glimpse, release + 1.5)(run)
    assert ex.mode == IDLE and ex.episodes == 1  # the glimpse was never a confirmed throw
    text = episode_text(state_of(ex))
    assert text == {"throws": 1, "executed": False, "confirmed": False, "hedges": 1,
                    "hedge_end": ex.hedge_end}  # fmt: skip
    assert ex.hedge_end in ("no_launch", "silence", "timeout")
    kind, detail = episode_end(state_of(ex))
    assert kind == "episode_end" and detail == text


@pytest.fixture(scope="module")
def world(small_tree_015, robot):
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World

    return World(load_tree(small_tree_015), robot, CFG, ServoConfig(), CameraModelConfig())


def test_feints_keep_the_shield_within_the_bound_and_come_home(world):
    from thinkfast.sim.lockstep import simulate
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    feints = sample_throws(ThrowConfig(), 0, 3, 8)  # 8 feints of seed 3
    hedged = 0
    for k, throw in enumerate(feints):
        out = simulate(world, throw, "tree-hedge-mean", seed=k)
        assert out.kind == "feint"
        assert out.displacement <= CFG.hedge.bound, out  # the arm's, measured
        assert out.home_again, out
        hedged += out.hedges > 0
    assert hedged >= 1  # the forward swings do start hedges: the bound is what was tested


# ---------------------------------------------------------------- at first-light speeds
SCALE = 0.2  # thinkfast-run --speed-scale at first light (tests/test_first_light.py)


@pytest.fixture(scope="module")
def slow_world(small_tree_015, robot):
    from thinkfast.daemon.cli import scale_limits
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World

    slow = scale_limits(robot, SCALE)
    return World(load_tree(small_tree_015), slow, _cfg("mean"), ServoConfig(), CameraModelConfig())


def _fly_home(world, throw, seed: int, miss: float):
    """Lockstep (thinkfast/sim/lockstep.py's loop) until the arm is home after the throw; the
    host leaves each packet unanswered with probability ``miss`` (the controller keeps its
    last reference, the next reply catches up). Returns the control core and the references
    the controller received."""
    from thinkfast.sim.camera import detection_payload, observe_cameras
    from thinkfast.sim.controller import SimController
    from thinkfast.sim.lockstep import LEAD
    from thinkfast.sim.throws import plane_crossing

    cfg, robot = world.cfg, world.robot
    t_rel = LEAD + throw.t_release
    dets = observe_cameras(throw, world.cameras, seed, t_rel)
    t_over = t_rel + plane_crossing(throw).t + cfg.throw.after_crossing
    sim = SimController(world.servo, q0=robot.home)
    core = world.parts.core(world.parts.executor("tree-hedge-mean"))
    rng = np.random.default_rng(seed)
    k, t = 0, 0.0
    while t < t_over or core.ex.mode != IDLE:
        assert t < t_over + 10.0, "not home 10 s after the throw"
        while k < len(dets) and dets[k].delivery_time <= t:
            core.on_detection(detection_payload(dets[k]), None, t)
            k += 1
        if t < 0.1 or rng.random() >= miss:
            reply = core.on_feedback(Feedback(round(t * 1000.0), sim.q), t)
            if reply is not None:
                sim.command(reply.q, reply.qd, t)
        sim.step(DT)
        t += DT
    return core, sim.commands()


@pytest.mark.parametrize(
    ("throw_id", "miss"),
    [("s1-16", 0.0), ("s1-3", 0.1)],
    ids=["return-after-hedge", "missed-cycles"],
)
def test_at_first_light_speed_the_supervisor_never_acts(slow_world, throw_id, miss):
    """At ``--speed-scale 0.2`` with the hedge on, every reference is within the scaled limits
    by construction, on the controller's clock: the supervisor changes none. Two ways it used
    to: the way home planned with the return limits' lower jerk from an arm still speeding up
    near the velocity limit (its speed rose past it before it fell), and a plan resumed after
    a missed cycle from an extrapolated acceleration no plan could hold at that speed."""
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    robot = slow_world.robot
    throw = {th.id: th for th in sample_throws(ThrowConfig(), 17, seed=1)}[throw_id]
    core, wire = _fly_home(slow_world, throw, int(throw_id.split("-")[1]), miss)
    assert core.ex.hedges >= 1 and core.ex.episodes == 1  # hedged, blocked or not, home
    assert (core.catch_ups > 20) == (miss > 0)
    assert np.max(np.abs(wire.q - robot.home)) > 0.05  # it did move
    assert core.sup.intervened == 0, {k: v for k, v in core.sup.counts.items() if v}
    cycles = np.round(np.diff(wire.t) / DT)[:, None]
    assert np.all(np.abs(wire.qd) <= robot.v_max + 1e-9)
    assert np.all(np.abs(np.diff(wire.qd, axis=0)) <= robot.a_max * DT * cycles + 1e-9)


def test_with_several_cameras_the_early_belief_takes_the_fusion_settings():
    """``[fusion] early_max_drop`` and ``early_prior_age`` replace ``[early]``'s with several
    cameras (the hedge stage's and the held-ball bench's early belief); one camera keeps
    ``[early]`` as it is."""
    from thinkfast.control.config import early_config
    from thinkfast.estimate.fusion import SIDE_CAMERA

    assert early_config(CFG) is CFG.early and not CFG.early.prior_age
    fusion = dataclasses.replace(CFG.fusion, early_max_drop=1 - CFG.early.max_drop)
    two = dataclasses.replace(CFG, cameras=(SIDE_CAMERA,), fusion=fusion)
    early = early_config(two)
    assert (early.max_drop, early.prior_age) == (1 - CFG.early.max_drop, True)
    assert early.depart_lateral == two.fusion.early_depart_lateral != CFG.early.depart_lateral
    back = {k: getattr(CFG.early, k) for k in ("max_drop", "prior_age", "depart_lateral")}
    assert dataclasses.replace(early, **back) == CFG.early
