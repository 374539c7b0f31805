"""Judge: the true ball (a sphere) against the shield disk along a joint history."""

import math

import numpy as np
import pytest

from thinkfast.robot.batch_fk import BatchFK
from thinkfast.sim.judge import interpolate_q, judge, sphere_disk_gap
from thinkfast.sim.throws import ThrowConfig, ball_state, make_throw, plane_crossing

T_REL = 1_763_800_000.0  # release, wall clock
R_BALL = ThrowConfig().ball_radius


@pytest.fixture(scope="module")
def home(robot):
    return np.array(robot.home, dtype=float)


@pytest.fixture(scope="module")
def pose(kin, home):
    return kin.shield(home)


def _throw(pose, dy=0.0, dz=0.0, flight_time=0.6):
    """A throw aimed at the shield centre offset by (dy, dz) [m] on the plane x = centre x."""
    c = pose.centre
    cfg = ThrowConfig(plane_distance=float(c[0]))
    aim = (float(c[1] + dy), float(c[2] + dz))
    return make_throw(cfg, np.array([c[0] + 7.0, aim[0], 1.5]), aim, flight_time)


def _hold(q):
    return np.array([T_REL - 1.0]), np.asarray(q, float)[None]


def test_ball_through_the_shield_centre_is_blocked_at_the_front_face(robot, kin, home, pose):
    assert pose.normal[0] > 0.999  # home: shield on the plane, facing the thrower
    th = _throw(pose)
    v = judge(th, *_hold(home), kin, th.plane_x, R_BALL, T_REL)
    assert v.blocked and v.why == "blocked" and v.miss_distance == 0.0
    t_cross = plane_crossing(th).t
    assert T_REL < v.t_contact < T_REL + t_cross

    p, _ = ball_state(th, v.t_contact - T_REL)
    face = pose.centre[0] + 0.5 * robot.shield_thickness + R_BALL
    assert p[0] == pytest.approx(face, abs=1e-4)


def test_ball_passing_1cm_outside_the_rim_is_not_blocked(robot, kin, home, pose):
    th = _throw(pose, dy=robot.shield_radius + R_BALL + 0.01)
    v = judge(th, *_hold(home), kin, th.plane_x, R_BALL, T_REL)
    assert not v.blocked and v.why == "missed" and math.isnan(v.t_contact)
    assert v.miss_distance == pytest.approx(0.01, abs=1e-3)


def test_ball_1cm_inside_the_rim_is_blocked(robot, kin, home, pose):
    th = _throw(pose, dz=-(robot.shield_radius + R_BALL - 0.01))
    assert judge(th, *_hold(home), kin, th.plane_x, R_BALL, T_REL).blocked


def _arrival(home, t_arrive):
    """At a parked pose (shield swung 0.6 rad aside) until ``t_arrive`` - 2 ms, then home."""
    away = home.copy()
    away[0] += 0.6
    t = np.array([T_REL - 1.0, t_arrive - 0.002, t_arrive, T_REL + 5.0])
    return t, np.stack([away, away, home, home])


def test_shield_arriving_10ms_late_is_not_a_block(kin, home, pose):
    th = _throw(pose)
    t_cross = T_REL + plane_crossing(th).t
    v = judge(th, *_arrival(home, t_cross + 0.010), kin, th.plane_x, R_BALL, T_REL)
    assert not v.blocked and v.why == "late"
    assert t_cross < v.when <= t_cross + 0.011
    assert v.miss_distance > 0.1  # the parked shield was nowhere near


def test_the_same_motion_20ms_early_blocks(kin, home, pose):
    th = _throw(pose)
    t_cross = T_REL + plane_crossing(th).t
    v = judge(th, *_arrival(home, t_cross - 0.020), kin, th.plane_x, R_BALL, T_REL)
    assert v.blocked and v.t_contact > t_cross - 0.020


def test_a_ball_missing_a_still_shield_by_far_is_a_plain_miss(kin, home, pose):
    th = _throw(pose, dy=0.8)
    v = judge(th, *_hold(home), kin, th.plane_x, R_BALL, T_REL)
    assert v.why == "missed" and v.miss_distance > 0.5


def test_sphere_disk_gap_on_the_face_the_rim_the_edge_and_inside():
    c, n = np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]])

    def gap(p):
        return sphere_disk_gap(np.array([p], float), c, n, 0.2, 0.005, 0.03)[0]

    assert gap([0.1, 0.05, 0.0]) == pytest.approx(0.1 - 0.005 - 0.03)  # in front of the face
    assert gap([0.0, 0.3, 0.0]) == pytest.approx(0.1 - 0.03)  # beside the rim
    assert gap([0.105, 0.0, 0.3]) == pytest.approx(math.hypot(0.1, 0.1) - 0.03)  # off the edge
    assert gap([0.002, 0.1, 0.0]) == pytest.approx(-0.003 - 0.03)  # inside the disk


def test_the_judge_poses_the_shield_as_kinematics_does(robot, kin):
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, (20, 6))
    T = BatchFK(robot).link_poses(q, until=robot.shield_link)[robot.shield_link]
    for i in range(len(q)):
        centre, normal = kin.shield(q[i])
        np.testing.assert_allclose(T[i, :3, 3], centre, atol=1e-12)
        np.testing.assert_allclose(T[i, :3, 2], normal, atol=1e-12)


def test_history_is_interpolated_linearly_and_held_outside():
    t = np.array([0.0, 1.0])
    q = np.array([np.zeros(6), np.arange(6.0)])
    out = interpolate_q(t, q, np.array([-1.0, 0.25, 2.0]))
    np.testing.assert_allclose(out, [np.zeros(6), 0.25 * np.arange(6.0), np.arange(6.0)])


def test_a_malformed_history_is_refused(kin, pose):
    th = _throw(pose)
    with pytest.raises(ValueError, match="increasing"):
        judge(th, np.array([1.0, 1.0]), np.zeros((2, 6)), kin, th.plane_x, R_BALL)
    with pytest.raises(ValueError, match="q_hist"):
        judge(th, np.array([1.0]), np.zeros((1, 5)), kin, th.plane_x, R_BALL)


def _excursion(home, peak, back_at, end):
    """Joint 1 goes 0.2 rad out from T_REL to T_REL + 0.5 s, then home by ``back_at`` (or never)."""
    t = T_REL - 1.0 + np.arange(0.0, end + 1.0, 0.004)
    q = np.tile(home, (len(t), 1))
    s = t - T_REL
    out = np.clip(s / 0.5, 0.0, 1.0)
    if back_at is not None:
        out = np.where(s > 0.5, np.clip((back_at - s) / (back_at - 0.5), 0.0, 1.0), out)
    q[:, 0] += peak * out
    return t, q


def test_feint_judge_measures_the_shield_excursion_and_when_it_is_home_again(kin, home):
    from thinkfast.sim.judge import judge_feint

    t, q = _excursion(home, 0.2, back_at=1.2, end=2.5)
    v = judge_feint(t, q, kin, home, T_REL)
    q_far = home.copy()
    q_far[0] += 0.2
    expect = np.linalg.norm(kin.shield(q_far).centre - kin.shield(home).centre)
    assert v.displacement == pytest.approx(expect, rel=1e-9) and expect > 0.1
    assert 1.2 <= v.home_after <= 1.21 and v.home_again
    late = judge_feint(*_excursion(home, 0.2, back_at=2.3, end=2.5), kin, home, T_REL)
    assert 2.3 <= late.home_after <= 2.31 and not late.home_again
    gone = judge_feint(*_excursion(home, 0.2, back_at=None, end=2.5), kin, home, T_REL)
    assert math.isnan(gone.home_after) and not gone.home_again
    short = judge_feint(*_excursion(home, 0.2, back_at=1.2, end=1.5), kin, home, T_REL)
    assert not short.home_again  # the history does not cover the 2 s window
    still = judge_feint(*_excursion(home, 0.0, back_at=1.2, end=2.5), kin, home, T_REL)
    assert still.displacement == 0.0 and still.home_after < 0.0 and still.home_again
