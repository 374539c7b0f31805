"""Braking kernels: a jerk-limited stop reaches rest, keeps a_max and j_max, and never reverses a
joint but one already turning round."""

import numpy as np
import pytest

from thinkfast.control.safety_brake import JerkLimitedStop, brake_velocity, turning
from thinkfast.control.safety_limits import make_limits

DT = 0.004
LIM = make_limits([-3.0] * 3, [3.0] * 3, [3.0, 3.0, 3.2], [12.0, 12.0, 15.0], [120.0, 120.0, 150.0])


def _run(next_v, v0, ticks=2000):
    vs = [np.asarray(v0, dtype=float)]
    for _ in range(ticks):
        vs.append(next_v(vs[-1], (vs[-1] - vs[-2]) / DT if len(vs) > 1 else np.zeros(3)))
        if not vs[-1].any():
            break
    return np.array(vs)


@pytest.mark.parametrize("v0", [[2.9, -3.0, 0.4], [0.01, -1e-6, 0.0], [-1.0, 1.0, 3.2]])
def test_brake_velocity_stops_without_reversing_within_a_max(v0):
    vs = _run(lambda v, a: brake_velocity(v, a, LIM, DT), v0)
    assert not vs[-1].any()
    assert (vs * np.sign(v0) >= 0).all()
    acc = np.diff(vs, axis=0) / DT
    assert (np.abs(acc) <= LIM.a_max * (1 + 1e-9)).all()
    jerk = np.diff(acc, axis=0) / DT
    assert (np.abs(jerk[1:]) <= 1.25 * LIM.j_max).all()


def test_brake_velocity_honours_jerk_from_full_acceleration_away():
    v0, a0 = np.array([1.0, -1.0, 0.5]), np.array([12.0, -12.0, 15.0])
    v1 = brake_velocity(v0, a0, LIM, DT)
    assert ((v1 - v0) / DT * np.sign(v0) >= LIM.a_max - LIM.j_max * DT - 1e-9).all()


def _stop_velocities(v0, a0, ticks=1000):
    """The planned stop's velocities, tick by tick from ``v0`` until every joint is at rest."""
    stop = JerkLimitedStop.plan(v0, a0, LIM)
    assert stop is not None
    vs = [np.asarray(v0, dtype=float)]
    for _ in range(ticks):
        vs.append(stop.next(DT))
        if not vs[-1].any():
            break
    return np.array(vs)


def test_jerk_limited_stop_follows_ruckigs_profile_to_rest():
    v0, a0 = np.array([2.5, -1.0, 0.0]), np.array([0.0, 3.0, 0.0])
    vs = _stop_velocities(v0, a0)
    assert not vs[-1].any() and (vs * np.sign(v0) >= 0).all()
    acc = np.diff(vs, axis=0) / DT
    assert (np.abs(acc) <= LIM.a_max * (1 + 1e-6)).all()
    assert len(vs) - 1 >= int(2.5 / 12.0 / DT)  # not faster than a_max allows


def test_a_joint_turning_round_as_the_stop_begins_passes_zero_and_keeps_j_max():
    """Joint 3 of a fault-campaign brake: -0.25 rad/s and +11.8 rad/s^2 (a^2 / 2j = 0.46 rad/s
    of change left at j_max 150). Cut at zero, its acceleration fell from about 8 to 0 in one
    tick (jerk 9 j_max); the stop now carries it through zero and back to rest within j_max.
    The other joints (along and against their motion, but able to stop) never reverse."""
    v0, a0 = np.array([1.0, -1.5, -0.25]), np.array([6.0, 3.0, 11.8])
    assert turning(v0, a0, LIM.j_max).tolist() == [False, False, True]
    vs = _stop_velocities(v0, a0)
    assert not vs[-1].any()
    assert (vs[:, :2] * np.sign(v0[:2]) >= 0).all()
    peak = vs[:, 2].max()
    assert 0.1 < peak <= a0[2] ** 2 / (2 * LIM.j_max[2]) - 0.25 + 1e-6  # through zero, bounded
    acc = np.diff(np.vstack([v0 - a0 * DT, vs]), axis=0) / DT  # a0 held before the stop
    assert (np.abs(acc) <= LIM.a_max * (1 + 1e-6)).all()
    jerk = np.diff(acc, axis=0) / DT
    assert (np.abs(jerk) <= 1.05 * LIM.j_max).all()


def test_jerk_limited_stop_refuses_a_non_finite_state():
    assert JerkLimitedStop.plan([np.nan, 0.0, 0.0], np.zeros(3), LIM) is None
    assert JerkLimitedStop.plan(np.zeros(3), [0.0, np.inf, 0.0], LIM) is None
