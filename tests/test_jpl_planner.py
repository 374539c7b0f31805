"""The ``jpl`` planner (thinkfast/control/planners/jpl.py): JPL's cubic predictor and its
sequential convex program (real OSQP) on the real robot model, and its plans through
``decide``.

Claims: the cubic predictor finds the crossing of an exact ballistic flight (a cubic holds a
parabola exactly, so only rounding is left); ``solve`` reaches a reachable wrist-centre goal
exactly within every limit, with states that are solver_base.integrate's; an unreachable goal
is a failure with a reason, never an exception; through ``decide``, a throw gets a steer
segment that puts the coplanar shield on the predicted point ``controller_lag`` before the
crossing and ends at rest; a failed solve keeps the previous plan and is counted.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.planners import registry
from thinkfast.control.planners.base import Belief, EpisodeLog, follow
from thinkfast.control.planners.jpl import JplPlanner, cubic_fit, first_root
from thinkfast.control.planners.solver_base import FAILURES, integrate
from thinkfast.control.segments import STEER
from thinkfast.control.timeline import Timeline
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.tree.file import load_tree

CFG = RunConfig()
G = CFG.filter.gravity
LAG = CFG.execution.controller_lag
FRAME = 0.02  # s: 50 Hz estimates
LATENCY = 0.02  # s: a belief reaches the planner this long after its stamp
RELEASE = 1.0  # s: on the plans' clock
START = np.array([4.0, -0.3, 1.4])  # m: the ball at release, in the plane's frame


def decide(pl, b, ep):
    """The planner's decision on ``b``, applied to its timeline as the executor applies it."""
    act = pl.decide(b, ep)
    follow(pl.timeline, ep, act.follow)
    return act


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


def planner(rtree, robot, **jpl) -> JplPlanner:
    cfg = dataclasses.replace(CFG, jpl=dataclasses.replace(CFG.jpl, **jpl))
    return JplPlanner(rtree, robot, cfg, Timeline(robot, cfg.execution))


def ballistic(aim_yz, flight: float, plane_x: float):
    """(state at t (6,), crossing time) of the drag-free flight from START that crosses the
    plane at ``aim_yz`` ``flight`` seconds after RELEASE."""
    target = np.array([plane_x, *aim_yz])
    v0 = (target - START) / flight
    v0[2] += 0.5 * G * flight

    def state(t: float) -> np.ndarray:
        s = t - RELEASE
        p = START + v0 * s + np.array([0.0, 0.0, -0.5 * G * s * s])
        return np.r_[p, v0 + np.array([0.0, 0.0, -G * s])]

    return state, RELEASE + flight


def belief(rtree, state, stamp: float, executing: bool = False, t_start=float("nan")):
    mean = state(stamp)
    c = rtree.crossing(mean, np.eye(6) * 1e-6, G)
    return Belief(stamp + LATENCY, stamp, c, mean, executing, t_start)


def shield_at(pl: JplPlanner, q123) -> np.ndarray:
    """The coplanar shield's centre at joints 1-3 ``q123``: wrist centre + reach * normal."""
    return pl.reach.position(q123) + pl.reach.reach * pl.normal


def test_jpl_is_registered_and_loads(rtree, robot):
    e = registry.get("jpl", online=True)
    assert e.load() is JplPlanner
    pl = planner(rtree, robot)
    assert pl.settings is pl.cfg.jpl and pl.rate == float("inf")  # every estimate is due


def test_cubic_fit_and_root_are_exact_on_a_cubic():
    t = np.linspace(-0.2, 0.0, 11)
    c = np.array([0.5, -4.9, -10.0, 5.0])
    coef = cubic_fit(t, np.c_[np.polyval(c, t), t, t * t])
    assert np.allclose(coef[0], c, atol=1e-9)
    assert np.allclose(coef[1], [0, 0, 1, 0], atol=1e-9)
    root = first_root(coef[0], 0.8, 0.0, 1.5)
    assert root is not None and abs(np.polyval(c, root) - 0.8) < 1e-12
    assert first_root(coef[0], 0.8, root + 1e-3, 1.5) is None  # no later crossing in range
    assert first_root(np.array([0.0, 0.0, 0.0, 1.0]), 0.8, 0.0, 1.5) is None  # a constant


@pytest.mark.parametrize("time_base", ["latest", "first"])
def test_the_cubic_predicts_an_exact_ballistic_crossing(rtree, robot, time_base):
    """An exact ballistic flight sampled at 50 Hz, the window (11 estimates) over its last
    0.2 s: a cubic polynomial can represent the parabola z(t) (and the lines x(t), y(t))
    exactly, so the least-squares fit is the flight itself and the crossing is found to
    rounding (asserted: 1 cm, 2 ms)."""
    pl = planner(rtree, robot, window=11, time_base=time_base)
    aim, flight = (0.2, 1.1), 0.6
    state, t_cross = ballistic(aim, flight, rtree.plane_x)
    stamps = RELEASE + FRAME * np.arange(1, 16)  # the last one 0.3 s into the flight
    preds = [pl.predict(belief(rtree, state, s)) for s in stamps]
    assert all(p is None for p in preds[:3])  # fewer than the cubic's 4 estimates
    p = preds[-1]
    assert len(pl._window) == 11 and pl._window[0][0] == pytest.approx(stamps[-1] - 0.2)
    assert np.linalg.norm(p.yz - aim) < 0.01 and abs(p.t_cross - t_cross) < 0.002
    pl.reset()  # a new throw: the window starts again
    assert pl.predict(belief(rtree, state, stamps[-1] + FRAME)) is None


def test_the_filter_predictor_is_the_beliefs_crossing(rtree, robot):
    pl = planner(rtree, robot, predictor="filter")
    state, t_cross = ballistic((0.2, 1.1), 0.6, rtree.plane_x)
    b = belief(rtree, state, RELEASE + FRAME)
    p = pl.predict(b)  # from the first estimate on: no window to fill
    assert np.allclose(p.yz, b.crossing.mean[:2]) and p.t_cross == b.stamp + b.crossing.mean[2]
    assert abs(p.t_cross - t_cross) < 1e-9


def test_solve_reaches_a_goal_near_home_within_the_limits(rtree, robot):
    pl = planner(rtree, robot)
    n = pl.n_arm
    x0 = np.r_[robot.home[:n], np.zeros(2 * n)]
    goal = pl.reach.position(robot.home[:n]) + np.array([0.0, 0.25, 0.15])
    sol = pl.solve(x0, goal, 0.4)
    assert sol.ok and sol.reason == "" and 1 <= sol.iterations <= pl.settings.scp_iterations
    assert sol.jerk.shape == (pl.settings.intervals, n) and sol.dt == pytest.approx(0.02)
    states = integrate(x0, sol.jerk, sol.dt)
    assert np.linalg.norm(pl.reach.position(states[-1, :n]) - goal) < 1e-3
    tol = 1 + 1e-4  # OSQP's tolerance, on the solver's share of the limits
    assert np.all(np.abs(sol.jerk) <= pl.j_max * tol)
    assert np.all(np.abs(states[:, n : 2 * n]) <= pl.v_max * tol)
    assert np.all(np.abs(states[:, 2 * n :]) <= pl.a_max * tol)
    assert np.all(states[:, :n] >= pl.q_lo - 1e-6) and np.all(states[:, :n] <= pl.q_hi + 1e-6)
    assert np.all(np.abs(states[:, 2 * n :]) <= np.asarray(robot.a_max[:n]))  # the real ones


@pytest.mark.parametrize(
    "offset, horizon",
    [((0.0, 3.0, 0.0), 0.4), ((0.0, 0.6, -0.5), 0.1)],
    ids=["out of the workspace", "out of time"],
)
def test_an_unreachable_goal_fails_with_a_reason(rtree, robot, offset, horizon):
    pl = planner(rtree, robot)
    n = pl.n_arm
    x0 = np.r_[robot.home[:n], np.zeros(2 * n)]
    goal = pl.reach.position(robot.home[:n]) + np.array(offset)
    sol = pl.solve(x0, goal, horizon)
    assert not sol.ok and sol.reason in FAILURES and sol.reason != "error"
    assert 1 <= sol.iterations <= pl.settings.scp_iterations


def fly(pl: JplPlanner, rtree, aim, flight, until: float):
    """Beliefs of the exact flight to ``aim`` through ``decide``, every 20 ms from release
    until ``until`` s into the flight; the executor's part: it has left at the first leave."""
    state, t_cross = ballistic(aim, flight, rtree.plane_x)
    ep, t_start, adopted = EpisodeLog(), float("nan"), []
    for stamp in RELEASE + FRAME * np.arange(1, int(round(until / FRAME)) + 1):
        b = belief(rtree, state, stamp, not np.isnan(t_start), t_start)
        before = pl.stats.adopted
        act = decide(pl, b, ep)
        if act.leave and np.isnan(t_start):
            t_start = b.t_now
        if pl.stats.adopted > before:
            adopted.append(pl.last)
    return t_cross, adopted


def test_decide_puts_the_shield_on_the_predicted_point_lag_early(rtree, robot):
    pl = planner(rtree, robot)
    aim, flight = (0.25, 1.15), 0.7
    t_cross, adopted = fly(pl, rtree, aim, flight, 0.66)
    assert len(adopted) >= 5 and pl.stats.frozen >= 1  # re-solved, then played out
    assert not any(pl.stats.failed.values())
    seg, pred = pl.timeline.segment, adopted[-1]
    assert seg.kind == STEER and abs(pred.t_cross - t_cross) < 0.002
    n = pl.n_arm
    q = seg.state(pred.t_cross - LAG)[:n]
    point = np.array([rtree.plane_x, *pred.yz])
    assert np.linalg.norm(shield_at(pl, q) - point) < 0.01
    assert np.linalg.norm(pred.yz - aim) < 0.01
    end = seg.state(seg.t_end + 1.0)
    assert np.allclose(end[n:], 0.0) and np.allclose(seg.end[n:], 0.0)  # at rest
    assert np.allclose(end[:n], seg.end[:n])


def test_a_failed_solve_keeps_the_previous_plan_and_is_counted(rtree, robot):
    pl = planner(rtree, robot)
    aim, flight = (0.25, 1.15), 0.7
    fly(pl, rtree, aim, flight, 0.2)
    seg, adopted = pl.timeline.segment, pl.stats.adopted
    assert seg.kind == STEER and adopted >= 1
    pl.a_max = pl.a_max * 1e-3  # the next QP cannot follow the plan in progress: infeasible
    state, _ = ballistic(aim, flight, rtree.plane_x)
    act = decide(pl, belief(rtree, state, RELEASE + 0.22, True, RELEASE), EpisodeLog())
    assert not act.leave and pl.timeline.segment is seg and pl.stats.adopted == adopted
    assert pl.stats.failed["infeasible"] == 1 and pl.stats.solves == adopted + 1
