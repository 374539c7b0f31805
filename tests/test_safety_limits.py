"""Admissibility kernels: every step they return is inside the limits and recoverable."""

import numpy as np
import pytest

from thinkfast.control.safety_limits import (
    SafetyError,
    TickConstants,
    filter_step,
    filter_tick,
    finite_vector,
    limit_step,
    make_limits,
    recoverable,
    velocity_bounds,
)

DT = 0.004
LIM = make_limits(
    [-3.0, -1.5, -4.0], [3.0, 2.0, 1.0], [3.0, 3.0, 3.2], [12.0, 12.0, 15.0], [120.0] * 3, 0.035
)


def _max_recoverable_speed(q):
    """Largest |v| towards the nearer limit that still brakes in time (per joint)."""
    room = np.minimum(LIM.q_max - q, q - LIM.q_min)
    a = LIM.a_max
    return np.minimum(LIM.v_max, a * (np.sqrt(0.25 * DT**2 + 2 * room / a) - 0.5 * DT))


def _random_recoverable_states(rng, count):
    for _ in range(count):
        q = rng.uniform(LIM.q_min, LIM.q_max)
        v = rng.uniform(-1.0, 1.0, q.size) * _max_recoverable_speed(q) * 0.999
        yield q, v


def test_make_limits_shrinks_by_the_margin_and_freezes():
    assert np.allclose(LIM.q_min, [-2.965, -1.465, -3.965])
    assert np.allclose(LIM.q_max, [2.965, 1.965, 0.965])
    with pytest.raises(ValueError):
        LIM.v_max[0] = 9.0


def test_limits_are_validated_naming_the_bad_array():
    with pytest.raises(SafetyError, match="no range"):
        make_limits([0.0], [0.05], [1.0], [1.0], [1.0], margin=0.03)
    with pytest.raises(SafetyError, match="v_max must be > 0"):
        make_limits([0.0], [1.0], [0.0], [1.0], [1.0])
    with pytest.raises(SafetyError, match="q_upper must hold 2 finite"):
        make_limits([0.0, 0.0], [1.0], [1.0], [1.0], [1.0])


def test_recoverable_matches_the_braking_distance():
    q = LIM.q_max - 0.1
    v = _max_recoverable_speed(q)
    assert recoverable(q, 0.999 * v, LIM, DT).all() and not recoverable(q, 1.001 * v, LIM, DT).any()


def test_velocity_bounds_hold_the_braking_velocity_of_every_recoverable_state():
    rng = np.random.default_rng(7)
    for q, v in _random_recoverable_states(rng, 500):
        lo, hi = velocity_bounds(q, v, LIM, DT)
        v_brake = v - np.sign(v) * np.minimum(np.abs(v), LIM.a_max * DT)
        assert (lo <= v_brake + 1e-12).all() and (v_brake <= hi + 1e-12).all()


def test_limit_step_from_a_recoverable_state_stays_recoverable_whatever_the_wish():
    rng = np.random.default_rng(11)
    for q, v in _random_recoverable_states(rng, 500):
        q2, v2 = limit_step(q, v, rng.normal(0.0, 50.0, q.size), LIM, DT)
        assert (q2 >= LIM.q_min).all() and (q2 <= LIM.q_max).all()
        assert (np.abs(v2 - v) <= LIM.a_max * DT * (1 + 1e-9)).all()
        assert recoverable(q2, v2 * (1 - 1e-9), LIM, DT).all()


def test_limit_step_is_a_pure_function_of_its_arrays():
    q, v = np.full(3, 0.3), np.full(3, 0.5)
    a = limit_step(q, v, np.full(3, 9.0), LIM, DT)
    b = limit_step(q, v, np.full(3, 9.0), LIM, DT)
    assert all((x == y).all() for x, y in zip(a, b, strict=True))
    assert (q == 0.3).all() and (v == 0.5).all()


def test_an_admissible_request_passes_unchanged():
    q, v = np.zeros(3), np.full(3, 0.5)
    v_req = v + 0.5 * LIM.a_max * DT
    q_req = q + 0.5 * (v + v_req) * DT
    out = filter_step(q, v, q_req, v_req, LIM, DT)
    assert out.kinds == () and (out.q == q_req).all() and (out.qd == v_req).all()


def test_a_request_failing_each_check_names_it_and_is_replaced():
    q, v = np.zeros(3), np.zeros(3)
    fast = filter_step(q, v, q + 0.5 * 10.0 * DT, np.full(3, 10.0), LIM, DT)
    assert fast.kinds == ("velocity", "acceleration", "position_limit")
    assert (np.abs(fast.qd) <= LIM.a_max * DT * (1 + 1e-9)).all()
    jump = filter_step(q, v, q + 0.5, v, LIM, DT)
    assert jump.kinds == ("position_step",) and (jump.q < 0.5).all()
    edge, v0, v1 = LIM.q_max - 0.01, np.full(3, 0.4), np.full(3, 0.44)  # cannot stop in time
    q1 = edge + 0.5 * (v0 + v1) * DT
    assert recoverable(edge, v0, LIM, DT).all() and not recoverable(q1, v1, LIM, DT).all()
    wall = filter_step(edge, v0, q1, v1, LIM, DT)
    assert "position_limit" in wall.kinds and recoverable(wall.q, wall.qd, LIM, DT).all()


def test_filter_tick_with_precomputed_constants_equals_filter_step():
    rng = np.random.default_rng(3)
    k = TickConstants.of(LIM, DT)
    for q, v in _random_recoverable_states(rng, 200):
        v_req = v + rng.normal(0.0, 0.1, 3)
        q_req = q + 0.5 * (v + v_req) * DT + rng.normal(0.0, 1e-4, 3)
        a, b = filter_step(q, v, q_req, v_req, LIM, DT), filter_tick(q, v, q_req, v_req, LIM, DT, k)
        assert a.kinds == b.kinds and (a.q == b.q).all() and (a.qd == b.qd).all()


@pytest.mark.parametrize("bad", [None, "x", [1.0, 2.0], [1.0, np.nan, 0.0], [[1.0], [2.0]]])
def test_finite_vector_refuses_wrong_shapes_types_and_values(bad):
    assert finite_vector(bad, 3) is None
    assert (finite_vector([1, 2, 3], 3) == [1.0, 2.0, 3.0]).all()
