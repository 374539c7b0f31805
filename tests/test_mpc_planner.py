"""The fixed-time MPC planner (thinkfast.control.planners.mpc), real CasADi + IPOPT on the default
robot.

Claims: a goal near home is reached in 0.4 s (the jerks, integrated as the executor's pieces
are, put the wrist centre within 1 mm of it) within every limit; an unreachable goal (too far,
or too far for the time) is a failed solution, never an exception; through ``decide`` the
timeline gets a steer segment whose shield (the coplanar wrist, full kinematics) is on the
predicted point at the crossing less the controller lag and which ends at rest; a failed solve
keeps the segment in progress and is counted; the warm start (the last solution shifted) takes
fewer IPOPT iterations than a cold one on the same problem; the design's fit predicts the
crossing of a ballistic flight and nothing from fewer than five estimates; IPOPT prints nothing.
Counts and positions only: nothing depends on the wall clock.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.planners import registry
from thinkfast.control.planners.base import Belief, EpisodeLog, follow
from thinkfast.control.planners.mpc import MpcPlanner, ipopt_reason
from thinkfast.control.planners.solver_base import integrate
from thinkfast.control.segments import STEER
from thinkfast.control.timeline import Timeline
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.estimate.crossing import crossing_point
from thinkfast.robot.wrist import CoplanarWrist
from thinkfast.tree.file import load_tree

CFG = RunConfig()
G = CFG.filter.gravity
TOL = 1e-6  # of the limits: IPOPT's bounds hold to its tolerance


def decide(pl, b, ep):
    """The planner's decision on ``b``, applied to its timeline as the executor applies it."""
    act = pl.decide(b, ep)
    follow(pl.timeline, ep, act.follow)
    return act


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


@pytest.fixture
def planner(rtree, robot):
    return MpcPlanner(rtree, robot, CFG, Timeline(robot, CFG.execution))


def _home_state(planner) -> np.ndarray:
    return planner.timeline.state(0.0)


def _within_limits(planner, states: np.ndarray, jerk: np.ndarray) -> None:
    n = planner.n_arm
    assert np.all(np.abs(states[:, n : 2 * n]) <= planner.v_max * (1 + TOL))
    assert np.all(np.abs(states[:, 2 * n :]) <= planner.a_max * (1 + TOL))
    assert np.all(np.abs(jerk) <= planner.j_max * (1 + TOL))
    assert np.all(states[:, :n] >= planner.q_lo - TOL) and np.all(
        states[:, :n] <= planner.q_hi + TOL
    )


def _ball(yz, tau: float, plane_x: float, x: float = 4.0) -> np.ndarray:
    """A ball state [X Y Z Vx Vy Vz] that crosses the plane at ``yz`` after ``tau`` [s]."""
    vx = (plane_x - x) / tau
    vy, vz = 0.5, 1.0
    y = yz[0] - vy * tau
    z = yz[1] - vz * tau + 0.5 * G * tau * tau
    return np.array([x, y, z, vx, vy, vz])


def _belief(rtree, mean, t_now: float, stamp: float = 0.0) -> Belief:
    c = rtree.crossing(mean, np.diag([1e-6] * 3 + [1e-4] * 3), G)
    assert c.ok
    return Belief(t_now, stamp, c, mean, False, math.nan)


def test_the_registry_names_it():
    e = registry.get("mpc", online=True)
    assert e.load() is MpcPlanner and not MpcPlanner.hedges and MpcPlanner.slow


def test_a_goal_near_home_is_reached_within_the_limits(planner, capfd):
    x0 = _home_state(planner)
    goal = planner.wc_goal(np.array([0.2, 1.1]))
    sol = planner.solve(x0, goal, 0.4, t0=0.0)
    assert sol.ok and sol.reason == "" and sol.iterations > 0
    assert sol.jerk.shape == (CFG.mpc.intervals, planner.n_arm)
    assert math.isclose(sol.dt * len(sol.jerk), 0.4)
    states = integrate(x0, sol.jerk, sol.dt)
    assert np.linalg.norm(planner.reach.position(states[-1, :3]) - goal) < 1e-3
    _within_limits(planner, states, sol.jerk)
    out, err = capfd.readouterr()
    assert "Ipopt" not in out + err and "EXIT" not in out + err  # no banner, no report


@pytest.mark.parametrize("yz, horizon", [((3.0, 1.0), 0.4), ((0.9, 0.3), 0.3)])
def test_an_unreachable_goal_is_a_failed_solution(planner, yz, horizon):
    x0 = _home_state(planner)
    goal = planner.wc_goal(np.array(yz))
    if yz[0] > 2:  # 3 m away: past the arm's reach
        assert np.linalg.norm(goal - planner.reach.position(x0[:3])) > 2.5
    sol = planner.solve(x0, goal, horizon, t0=0.0)
    assert not sol.ok and sol.reason in ("infeasible", "iterations")
    assert sol.jerk.shape == (0, planner.n_arm)


def test_the_soft_terminal_goes_as_near_as_the_limits_allow_where_the_hard_one_fails(rtree, robot):
    """mpc-soft: a crossing 0.9 m aside in 0.3 s is out of reach (the hard terminal fails, as
    above); the soft one solves, within every limit, and ends nearer the goal than home is."""
    import dataclasses

    cfg = registry.get("mpc-soft").configure(CFG)
    assert cfg.mpc.terminal == "soft" and CFG.mpc.terminal == "hard"
    soft = MpcPlanner(rtree, robot, cfg, Timeline(robot, cfg.execution))
    x0 = _home_state(soft)
    goal = soft.wc_goal(np.array([0.9, 0.3]))
    sol = soft.solve(x0, goal, 0.3, t0=0.0)
    assert sol.ok, sol
    states = integrate(x0, sol.jerk, sol.dt)
    _within_limits(soft, states, sol.jerk)
    start = np.linalg.norm(soft.reach.position(x0[:3]) - goal)
    end = np.linalg.norm(soft.reach.position(states[-1, :3]) - goal)
    assert end < 0.8 * start, (start, end)
    # and a reachable goal is still reached (the penalty is not a looser target)
    near = soft.wc_goal(np.array([0.1, 1.1]))
    sol = soft.solve(x0, near, 0.4, t0=0.0)
    assert sol.ok
    states = integrate(x0, sol.jerk, sol.dt)
    assert np.linalg.norm(soft.reach.position(states[-1, :3]) - near) < 0.005
    assert dataclasses.replace(cfg.mpc, terminal="hard") == CFG.mpc


def test_a_horizon_that_is_no_time_is_an_error_not_an_exception(planner):
    sol = planner.solve(_home_state(planner), planner.wc_goal(np.array([0.1, 1.0])), 0.0, 0.0)
    assert not sol.ok and sol.reason == "error"


def test_decide_puts_the_shield_on_the_predicted_point_at_the_crossing_less_the_lag(
    planner, rtree, robot, kin
):
    yz = np.array([0.1, 1.1])
    b = _belief(rtree, _ball(yz, 0.4, rtree.plane_x), t_now=0.01)
    act = decide(planner, b, EpisodeLog())
    assert act.leave and planner.stats.adopted == 1 and planner.stats.solves == 1
    seg = planner.timeline.segment
    assert seg.kind == STEER and seg.t0 == 0.01
    t_cross = b.stamp + float(b.crossing.mean[2])
    s = planner.timeline.state(t_cross - planner.lag)
    wrist = CoplanarWrist(robot).solve_one(s[:3], robot.home[3:])
    shield = kin.shield(np.r_[s[:3], wrist])
    target = np.r_[rtree.plane_x, b.crossing.mean[:2]]
    assert np.linalg.norm(shield.centre - target) < 0.01
    assert np.allclose(shield.normal, [1.0, 0.0, 0.0], atol=1e-6)
    end = planner.timeline.state(seg.t0 + seg.duration + 0.1)
    assert np.allclose(end[3:], 0.0, atol=1e-9)  # at rest once the stop after it ended
    assert np.allclose(end, seg.end, atol=1e-6)
    # the next belief is not due before the rate's period: the plan goes on
    assert not decide(planner, b._replace(t_now=0.03), EpisodeLog()).leave
    assert planner.stats.solves == 1 and planner.timeline.segment is seg


def test_a_failed_solve_keeps_the_segment_in_progress_and_is_counted(planner, rtree):
    ok = _belief(rtree, _ball(np.array([0.1, 1.1]), 0.4, rtree.plane_x), t_now=0.01)
    assert decide(planner, ok, EpisodeLog()).leave
    seg = planner.timeline.segment
    far = _belief(rtree, _ball(np.array([3.0, 1.1]), 0.4, rtree.plane_x), t_now=0.07)
    act = decide(planner, far, EpisodeLog())
    assert not act.leave and planner.timeline.segment is seg
    failed = planner.stats.failed
    assert failed["infeasible"] + failed["iterations"] == 1 and planner.stats.solves == 2
    assert planner.stats.adopted == 1
    d = planner.stats.as_dict()
    assert d["solves"] == 2 and sum(d["failed"].values()) == 1


def test_the_warm_start_takes_fewer_iterations_than_a_cold_one(planner):
    x0 = _home_state(planner)
    goal = planner.wc_goal(np.array([0.5, 0.8]))
    first = planner.solve(x0, goal, 0.4, t0=0.0)
    assert first.ok
    # 50 ms on: the plan's state then, a goal moved by 3 mm, the shrunk horizon
    shift = 0.05
    states = integrate(x0, first.jerk, first.dt)
    k = int(shift / first.dt)
    x1 = integrate(states[k], first.jerk[k : k + 1], shift - k * first.dt)[-1]
    goal1 = goal + np.array([0.0, 0.003, -0.002])
    warm = planner.solve(x1, goal1, 0.4 - shift, t0=shift)
    planner.reset()  # forget the last solution: a cold start
    cold = planner.solve(x1, goal1, 0.4 - shift, t0=shift)
    assert warm.ok and cold.ok
    assert warm.iterations < cold.iterations
    for sol in (warm, cold):
        end = integrate(x1, sol.jerk, sol.dt)[-1]
        assert np.linalg.norm(planner.reach.position(end[:3]) - goal1) < 1e-3


def test_the_fit_predicts_a_ballistic_crossing_from_five_estimates(rtree, robot):
    cfg = RunConfig()
    cfg = registry.Entry("x", MpcPlanner, settings=(("mpc.predictor", "fit"),)).configure(cfg)
    p = MpcPlanner(rtree, robot, cfg, Timeline(robot, cfg.execution))
    s0 = _ball(np.array([0.2, 1.0]), 0.5, rtree.plane_x)
    c = rtree.crossing(s0, np.eye(6) * 1e-6, G)
    preds = []
    for k in range(6):
        t = 0.01 * k
        s = np.r_[s0[:3] + s0[3:] * t - [0, 0, 0.5 * G * t * t], s0[3:] - [0, 0, G * t]]
        b = Belief(t + 0.005, t, c, s, False, math.nan)
        preds.append(p.predict(b))
    assert all(x is None for x in preds[:4])  # fewer than five estimates: no fit
    last = preds[-1]
    want = crossing_point(s0, rtree.plane_x, G)
    assert np.allclose(last.yz, want[:2], atol=1e-6) and math.isclose(
        last.t_cross, want[2], abs_tol=1e-9
    )
    p.reset()
    assert p.predict(b) is None  # the window is the throw's: gone with it


def test_ipopt_statuses_map_to_the_failures():
    assert ipopt_reason("Solve_Succeeded") == "" == ipopt_reason("Solved_To_Acceptable_Level")
    assert ipopt_reason("Infeasible_Problem_Detected") == "infeasible"
    assert ipopt_reason("Maximum_Iterations_Exceeded") == "iterations"
    assert ipopt_reason("Invalid_Number_Detected") == "error"
