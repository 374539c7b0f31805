"""Simulated throws: drag ODE, release velocity by shooting, sampling ranges, throw-set files."""

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from thinkfast.config import from_dict, to_dict
from thinkfast.errors import ConfigError, ThinkfastError
from thinkfast.sim.throws import (
    ThrowConfig,
    ball_positions,
    ball_state,
    ball_states,
    make_throw,
    plane_crossing,
    sample_throws,
)
from thinkfast.sim.throwset import load_throw_set, save_throw_set

CFG = ThrowConfig()
STILL = dataclasses.replace(CFG, thrower=dataclasses.replace(CFG.thrower, mix=(1.0, 0.0, 0.0)))


@pytest.fixture(scope="module")
def throws():
    """Still holds: the flight model's tests (wind-ups: tests/test_sim_thrower.py)."""
    return sample_throws(STILL, 40, seed=11)


def test_solved_throws_hit_their_aim_point_within_1mm_at_the_flight_time(throws):
    for th in throws:
        p, _ = ball_state(th, th.flight_time)
        target = np.array([CFG.plane_distance, *th.aim])
        assert np.linalg.norm(p - target) < 1e-3
        c = plane_crossing(th)
        assert abs(c.t - th.flight_time) < 1e-4
        assert math.hypot(c.y - th.aim[0], c.z - th.aim[1]) < 1e-3


def test_integration_matches_a_tight_adaptive_solver(throws):
    for th in throws[:5]:

        def f(_, y, k=th.drag, g=th.gravity):
            v = y[3:]
            return np.concatenate([v, -k * np.linalg.norm(v) * v - [0.0, 0.0, g]])

        ts = np.linspace(0.0, th.flight_time, 23)
        y0 = np.concatenate([th.p_release, th.v_release])
        ref = solve_ivp(f, (0, ts[-1]), y0, "DOP853", t_eval=ts, rtol=1e-12, atol=1e-12)
        p, v = ball_states(th, ts)
        np.testing.assert_allclose(p, ref.y[:3].T, atol=1e-8)
        np.testing.assert_allclose(v, ref.y[3:].T, atol=1e-8)


def test_draws_stay_inside_the_configured_ranges(throws):
    def inside(x, r):
        return r[0] <= x <= r[1]

    for th in throws:
        assert inside(th.p_release[0] - CFG.plane_distance, CFG.release_distance)
        assert inside(th.p_release[1], CFG.release_lateral)
        assert inside(th.p_release[2], CFG.release_height)
        assert inside(th.flight_time, CFG.flight_time)
        assert inside(th.aim[0], CFG.aim_y) and inside(th.aim[1], CFG.aim_z)
        assert inside(th.t_release, CFG.hold_time)
        assert (np.abs(th.hand_amp) <= CFG.hand_motion).all()
    times = np.array([th.flight_time for th in throws])
    assert times.min() < 0.5 and times.max() > 0.7  # the whole range is used


def test_sampling_is_deterministic_by_seed_and_each_throw_independent_of_n():
    a, b = sample_throws(CFG, 6, seed=3), sample_throws(CFG, 3, seed=3)
    for x, y in zip(a[:3], b, strict=True):
        assert x.id == y.id
        np.testing.assert_array_equal(x.v_release, y.v_release)
    c = sample_throws(CFG, 3, seed=4)
    assert not np.allclose(a[0].p_release, c[0].p_release)
    assert [t.id for t in b] == ["s3-0", "s3-1", "s3-2"]


def test_drag_k_is_that_of_a_tennis_ball():
    k = CFG.drag_k()
    assert k == pytest.approx(0.0204, rel=0.01)
    assert k * 15.0**2 == pytest.approx(4.6, rel=0.01)  # docs/FACTS.md: ~4.6 m/s^2 at 15 m/s


def test_drag_makes_the_ball_slower_than_gravity_only(throws):
    for th in throws[:10]:
        free = th._replace(drag=0.0)
        _, v_drag = ball_state(th, th.flight_time)
        _, v_free = ball_state(free, th.flight_time)
        assert np.linalg.norm(v_drag) < np.linalg.norm(v_free) - 0.5
        assert plane_crossing(th).t > plane_crossing(free).t + 0.01


def test_gravity_only_motion_is_exact_ballistics():
    th = make_throw(CFG, np.array([7.5, 0.2, 1.4]), (0.0, 1.0), 0.6)
    free = th._replace(drag=0.0)
    t = np.linspace(0.0, 0.9, 11)
    expect = free.p_release + free.v_release * t[:, None]
    expect[:, 2] -= 0.5 * free.gravity * t**2
    np.testing.assert_allclose(ball_positions(free, t), expect, atol=1e-12)


def test_ball_is_in_hand_before_release_and_leaves_from_the_release_point(throws):
    th = throws[0]
    t = np.linspace(-th.t_release, 0.0, 50)
    p, v = ball_states(th, t)
    assert np.abs(p - th.p_release).max() <= 2 * CFG.hand_motion
    assert np.linalg.norm(v[:-1], axis=1).max() < 0.05  # at rest but for the hand (t < 0)
    np.testing.assert_allclose(p[-1], th.p_release, atol=1e-12)
    p0, v0 = ball_state(th, 0.0)
    np.testing.assert_allclose(v0, th.v_release)


def test_throw_set_round_trip(tmp_path, throws):
    path = tmp_path / "set.json"
    save_throw_set(path, throws, CFG)
    loaded = load_throw_set(path)
    assert loaded.config == CFG
    assert len(loaded.throws) == len(throws)
    for a, b in zip(throws, loaded.throws, strict=True):
        for name in a._fields:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert plane_crossing(loaded.throws[7]).t == plane_crossing(throws[7]).t


def test_unknown_version_is_refused_naming_the_path(tmp_path, throws):
    path = tmp_path / "future.json"
    save_throw_set(path, throws[:1], CFG)
    doc = json.loads(path.read_text())
    doc["version"] = 3
    path.write_text(json.dumps(doc))
    with pytest.raises(ThinkfastError, match="future.json.*version 3"):
        load_throw_set(path)


@pytest.mark.parametrize("text", ["not json", '{"format": "other", "version": 1}', "[]"])
def test_files_that_are_not_throw_sets_are_refused(tmp_path, text):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ThinkfastError, match="bad.json"):
        load_throw_set(path)


GOLDEN_V1 = """{"format": "thinkfast-throws", "version": 1, "config": {"plane_distance": 0.8},
 "throws": [{"id": "s0-0", "t_release": 0.5, "p_release": [7.8, 0.0, 1.5],
  "v_release": [-13.0, 0.0, 3.0], "drag": 0.02, "aim": [0.0, 1.0], "flight_time": 0.6,
  "gravity": 9.81, "plane_x": 0.8, "hand_amp": [0.0, 0.0, 0.0], "hand_freq": [1.0, 1.0, 1.0],
  "hand_phase": [0.0, 0.0, 0.0]}]}"""


def test_golden_v1_document_loads_with_config_defaults(tmp_path):
    path = tmp_path / "golden.json"
    path.write_text(GOLDEN_V1)
    ts = load_throw_set(path)
    assert ts.config == STILL  # the defaults, and the all-still mix a version 1 set was drawn by
    (th,) = ts.throws
    assert th.id == "s0-0" and th.flight_time == 0.6
    np.testing.assert_array_equal(th.v_release, [-13.0, 0.0, 3.0])


def test_config_loads_from_toml_tables_and_refuses_inverted_ranges():
    assert from_dict(ThrowConfig, to_dict(CFG), "x.toml") == CFG
    with pytest.raises(ConfigError, match="flight_time"):
        from_dict(ThrowConfig, {"flight_time": [0.8, 0.4]}, "x.toml")


def _grid_with_arrays(y0, t_end, k, g):
    """The grid as the array RK4 step gives it (the reference for the per-row integrator)."""
    from thinkfast.sim.throws import STEP, _rk4

    n = int(math.floor(t_end / STEP + 1e-9))
    out = np.empty((n + 1, *y0.shape))
    out[0] = y0
    for i in range(n):
        out[i + 1] = _rk4(out[i], STEP, k, g)
    return out


def test_the_per_row_integrator_equals_the_array_step_bit_for_bit(throws):
    from thinkfast.sim.throws import _grid, _rk4, _rk4_row

    rng = np.random.default_rng(3)
    y0 = np.concatenate([rng.uniform(-8, 8, (200, 3)), rng.uniform(-25, 25, (200, 3))], axis=1)
    for k in (0.0, CFG.drag_k(), 0.05):
        for h in (0.005, 0.0013, 1e-7, 0.4):
            rows = np.array([_rk4_row(tuple(y), h, k, 9.81) for y in y0.tolist()])
            assert np.array_equal(rows, _rk4(y0, h, k, 9.81)), (k, h)
        assert np.array_equal(_grid(y0[:4], 0.9, k, 9.81), _grid_with_arrays(y0[:4], 0.9, k, 9.81))
    for th in throws[:10]:  # the flown states and the crossing, as the array steps give them
        y = np.concatenate([th.p_release, th.v_release])[None]
        ref = _grid_with_arrays(y, 1.2, th.drag, th.gravity)[:, 0]
        assert np.array_equal(_grid(y, 1.2, th.drag, th.gravity)[:, 0], ref)
        i = int(np.argmax(ref[:, 0] <= th.plane_x))
        prev, s = ref[i - 1 : i], (ref[i - 1, 0] - th.plane_x) / -ref[i - 1, 3]
        for _ in range(8):
            x = _rk4(prev, s, th.drag, th.gravity)[0]
            s -= (x[0] - th.plane_x) / x[3]
        x = _rk4(prev, s, th.drag, th.gravity)[0]
        c = plane_crossing(th)
        assert (c.t, c.y, c.z) == ((i - 1) * 0.005 + s, x[1], x[2]) and np.array_equal(c.v, x[3:])
