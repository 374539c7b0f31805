"""The tree planner's motion choice (thinkfast.decide.choice): candidates, clocks, values.

Real Ruckig moves on the default robot's limits, real forward kinematics; values checked against
a Monte Carlo of the judge's geometry on the same joint paths.
"""

from __future__ import annotations

import numpy as np
import pytest
from path_mc import judge_block

from thinkfast.control.segments import Steering, hold
from thinkfast.decide.choice import CONTINUE, DIRECT, ChoiceConfig, Chooser
from thinkfast.robot.ik import solve_shield_ik
from thinkfast.robot.shield_path import ShieldSampler

PLANE_X = 0.8
BALL_R = 0.0335


@pytest.fixture(scope="module")
def setup(robot, kin):
    """A 5 x 5 goal grid on the plane, y -0.6..0.6 m, z 0.6..1.4 m (shield IK, coplanar)."""
    sampler = ShieldSampler(robot)
    home = np.asarray(robot.home[:3], dtype=float)
    gy, gz = np.meshgrid(np.linspace(-0.6, 0.6, 5), np.linspace(0.6, 1.4, 5))
    goal_q = []
    for y, z in zip(gy.ravel(), gz.ravel(), strict=True):
        r = solve_shield_ik(kin, np.array([PLANE_X, y, z]), np.array([1.0, 0, 0]), robot.home)
        assert r.converged
        goal_q.append(r.q[:3])
    goal_q = np.array(goal_q)
    c = sampler.centres(goal_q)
    assert np.allclose(c[:, 0], PLANE_X, atol=1e-6)
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    chooser = Chooser(goal_q, c[:, 1:], robot, PLANE_X, BALL_R, steer, ChoiceConfig())
    return chooser, goal_q, c, home


def _belief(yz, tau, s_yz=0.05, s_tau=0.02):
    return np.array([*yz, tau]), np.diag([s_yz**2, s_yz**2, s_tau**2])


def test_candidates_are_nearest_first_and_always_hold_the_goal_nearest_the_mean(setup):
    chooser, _, c, _ = setup
    goals = chooser.candidate_goals(c[7, 1:], np.diag([1e-4, 1e-4]))
    assert goals[0] == 7
    assert len(goals) == chooser.cfg.candidates
    # a belief stretched along y ranks goals along y before nearer ones across it
    wide = chooser.candidate_goals(c[12, 1:], np.diag([1.0, 1e-4]))
    assert wide[0] == 12
    same_row = np.abs(chooser.goal_yz[wide[1:3], 1] - c[12, 2]) < 1e-9
    assert same_row.all()


def test_a_ball_at_a_goal_with_time_to_spare_is_met_there_with_its_disk_mass(setup):
    chooser, goal_q, c, home = setup
    mean, cov = _belief(c[3, 1:], 1.5)
    state = np.r_[home, np.zeros(6)]
    best, options = chooser.choose(mean, cov, None, 0.0, 0.0, 0.02, state, hold(state, 0.0))
    assert best.kind == DIRECT and best.goal == 3
    rho = chooser.rho
    assert best.value == pytest.approx(1.0 - np.exp(-(rho**2) / (2 * 0.05**2)), abs=2e-3)
    assert options[0].kind == CONTINUE


def test_waiting_is_chosen_when_the_ball_comes_at_the_shield_where_it_is(setup):
    chooser, _, _, home = setup
    state = np.r_[home, np.zeros(6)]
    here = chooser.sampler.centres(home)
    mean, cov = _belief(here[1:], 0.3)
    best, _ = chooser.choose(mean, cov, None, 0.0, 0.0, 0.02, state, hold(state, 0.0))
    assert best.kind == CONTINUE and best.value > 0.99


def test_planning_later_is_the_same_as_a_ball_arriving_sooner(setup):
    """The clocks: commanding from t_plan with lag L leaves tau - (t_plan + L - t_belief)."""
    chooser, _, c, home = setup
    state = np.r_[home, np.zeros(6)]
    seg = hold(state, -1.0)
    mean, cov = _belief(c[0, 1:], 0.45)
    _, a = chooser.choose(mean, cov, None, 0.0, 0.1, 0.02, state, seg)
    mean2 = mean - np.array([0.0, 0.0, 0.1])
    _, b = chooser.choose(mean2, cov, None, 0.0, 0.0, 0.02, state, seg)
    va = {o.goal: o.value for o in a}
    vb = {o.goal: o.value for o in b}
    assert va.keys() == vb.keys()
    for g, v in va.items():
        assert v == pytest.approx(vb[g], abs=1e-9)


def test_a_shield_still_moving_at_the_crossing_earns_what_the_judge_gives_it(setup):
    """The ball crosses at the goal while the move is still arriving: the at-rest reward says
    about zero, the judge's Monte Carlo (sphere against the moving disk) says more, and the
    choice's value agrees with the judge."""
    chooser, goal_q, c, home = setup
    state = np.r_[home, np.zeros(6)]
    traj = chooser.steer.to_rest(state, goal_q[0])
    arrive = traj.duration + 0.02
    mean, cov = _belief(c[0, 1:], arrive - 0.06, s_yz=0.04, s_tau=0.015)
    approach = np.array([-12.0, 0.0, -2.0])
    _, options = chooser.choose(mean, cov, approach, 0.0, 0.0, 0.02, state, hold(state, 0.0))
    direct = next(o for o in options if o.goal == 0)
    times = np.arange(0.0, arrive + 0.2, 0.002)
    q = np.array([traj.at_time(min(t, traj.duration))[0] for t in times])
    centres = chooser.sampler.centres(q)
    ref = judge_block(
        times, centres, mean, cov, tuple(chooser.geom), approach, 0.02, 20000,
        np.random.default_rng(5),
    )  # fmt: skip
    assert ref > 0.2  # moving, yet it blocks often: the at-rest reward would score ~0
    assert direct.value == pytest.approx(ref, abs=0.02)


def test_continuing_is_kept_unless_a_new_move_is_worth_the_margin(setup):
    chooser, goal_q, c, home = setup
    state = np.r_[home, np.zeros(6)]
    traj = chooser.steer.to_rest(state, goal_q[12])
    from thinkfast.control.segments import STEER, Segment

    seg = Segment(STEER, 0.0, traj, np.r_[goal_q[12], np.zeros(6)], traj.duration, 12)
    mid = np.array([*traj.at_time(0.1)[0], *traj.at_time(0.1)[1], *traj.at_time(0.1)[2]])
    mean, cov = _belief(c[12, 1:], 1.2)
    best, options = chooser.choose(mean, cov, None, 0.0, 0.1, 0.02, mid, seg)
    assert best.kind == CONTINUE  # the direct move to goal 12 is the same motion: no switch
    same = next(o for o in options if o.goal == 12)
    assert same.value == pytest.approx(options[0].value, abs=1e-3)


def test_a_new_chooser_builds_the_disk_table_before_its_first_decision(setup, robot):
    """The table takes ~0.1 s to build: in the first decision of a daemon that is 26 unanswered
    EGM cycles (measured). The chooser builds it when it is made."""
    from thinkfast.decide import iso_disk

    chooser, goal_q, c, _ = setup
    iso_disk._tables.cache_clear()
    Chooser(goal_q, c[:, 1:], robot, PLANE_X, BALL_R, chooser.steer, ChoiceConfig())
    assert iso_disk._tables.cache_info().currsize == 1


def test_joint_paths_in_one_pass_equal_at_time_sampling_bit_for_bit(setup, kernel_choice):
    """Many samples are read from the trajectories' phases in one pass (numpy or compiled):
    the same joints as Ruckig's at_time, for a moving segment in progress and a held one."""
    from types import SimpleNamespace

    from thinkfast.decide.choice import BATCH_SAMPLES, _joint_paths, _sample

    chooser, goal_q, _, home = setup
    state = np.r_[home, np.zeros(6)]
    trajs = [chooser.steer.to_rest(state, goal_q[g]) for g in (0, 6, 12, 24)]
    times = np.arange(-2, 200) * 0.02
    moving = SimpleNamespace(traj=trajs[0], end=None)
    held = SimpleNamespace(traj=None, end=np.r_[goal_q[3], np.zeros(6)])
    for current in (moving, held):
        shifted = times + 0.13
        got = _joint_paths(current, shifted, trajs[1:], times)
        want = np.stack(
            [_sample(current.traj, shifted, current.end)]
            + [_sample(t, times, None) for t in trajs[1:]]
        )
        assert len(times) * len(trajs) >= BATCH_SAMPLES  # numpy: the one-pass path is tested
        assert np.array_equal(got, want)


def test_few_joint_path_samples_equal_one_at_time_per_sample(setup, kernel_choice):
    """Few samples, before the start, inside and past the end: the same joints as one
    at_time per sample (numpy: one at_time per distinct clipped time; or compiled)."""
    from types import SimpleNamespace

    from thinkfast.decide.choice import BATCH_SAMPLES, _joint_paths, _sample

    chooser, goal_q, _, home = setup
    state = np.r_[home, np.zeros(6)]
    trajs = [chooser.steer.to_rest(state, goal_q[g]) for g in (0, 6, 12)]
    times = np.arange(-3, 90) * 0.02
    assert times[-1] > max(t.duration for t in trajs) and times[0] < 0.0
    moving = SimpleNamespace(traj=trajs[0], end=None)
    held = SimpleNamespace(traj=None, end=np.r_[goal_q[3], np.zeros(6)])
    for current in (moving, held):
        shifted = times - 0.05
        got = _joint_paths(current, shifted, trajs[1:], times)
        want = np.stack(
            [_sample(current.traj, shifted, current.end)]
            + [_sample(t, times, None) for t in trajs[1:]]
        )
        assert len(times) * len(trajs) < BATCH_SAMPLES  # numpy: the at_time path is tested
        assert np.array_equal(got, want)
