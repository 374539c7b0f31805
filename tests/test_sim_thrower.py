"""Thrower model: wind-ups and feints, their ranges and continuity, mixes, throw-set versions."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import assert_one_line_error, run_cli
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.errors import ConfigError, NoSolutionError, ThinkfastError
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.thrower import MINJERK_PEAK, STILL_MIX, ThrowerConfig, parse_mix
from thinkfast.sim.throws import ThrowConfig, ball_states, plane_crossing, sample_throws
from thinkfast.sim.throwset import load_throw_set, save_throw_set

DATA = Path(__file__).parent / "data"
CFG = ThrowConfig()
TC = CFG.thrower


def _cfg(mix):
    return dataclasses.replace(CFG, thrower=dataclasses.replace(TC, mix=mix))


@pytest.fixture(scope="module")
def windups():
    return sample_throws(_cfg((0.0, 1.0, 0.0)), 60, seed=13)


@pytest.fixture(scope="module")
def feints():
    return sample_throws(_cfg((0.0, 0.0, 1.0)), 30, seed=13)


@pytest.fixture(scope="module")
def stills():
    """The same draws as ``windups`` and ``feints``, every throw still."""
    return sample_throws(_cfg(STILL_MIX), 60, seed=13)


def _phases(th):
    """Start of the back swing and of the forward swing [s after release]."""
    return -th.forward_time - th.back_time, -th.forward_time


def test_wind_up_position_and_velocity_are_continuous_at_the_release_and_every_phase(windups):
    for th in windups:
        for t in (*_phases(th), 0.0):
            (p0, p1), (v0, v1) = ball_states(th, np.array([t - 1e-9, t]))
            speed = np.linalg.norm(th.v_release)
            assert np.linalg.norm(p1 - p0) < speed * 1e-9 + 1e-12, (th.id, t)
            assert np.linalg.norm(v1 - v0) < 1e-6, (th.id, t)  # acceleration x 1 ns at most
        _, v = ball_states(th, np.array([-1e-12, 0.0]))
        np.testing.assert_allclose(v, [th.v_release, th.v_release], atol=1e-9)


def test_wind_up_velocity_is_the_derivative_of_its_position(windups):
    for th in windups[:10]:
        t = np.linspace(-th.t_release, 0.02, 40001)
        p, v = ball_states(th, t)
        mid = (p[1:] - p[:-1]) / np.diff(t)[:, None]  # central difference at the midpoints
        assert np.abs(mid - 0.5 * (v[1:] + v[:-1])).max() < 2e-3  # m/s, step 36 us


def test_wind_up_swings_stay_inside_their_configured_ranges(windups, stills):
    def inside(x, r):
        return r[0] - 1e-12 <= x <= r[1] + 1e-12

    for th, st in zip(windups, stills, strict=True):
        assert th.kind == "windup"
        travel = float(np.linalg.norm(th.forward_swing))
        speed = float(np.linalg.norm(th.v_release))
        assert inside(th.forward_time, TC.forward_time) and inside(travel, TC.forward_distance)
        assert inside(travel / (speed * th.forward_time), TC.forward_mean_speed)
        assert inside(th.back_time, TC.back_time)
        assert inside(float(np.linalg.norm(th.back_swing)), TC.back_distance)
        assert inside(float(np.linalg.norm(th.back_sag)), TC.back_sag)
        drop = np.arcsin(-th.back_swing[2] / np.linalg.norm(th.back_swing))
        assert inside(drop, TC.back_drop)  # back swing goes down ...
        assert np.dot(th.back_swing[:2], th.v_release[:2]) < 0.0  # ... and back
        cos = np.dot(th.forward_swing, th.v_release) / (travel * speed)
        assert cos > 1.0 - 1e-12  # the forward swing runs along the throw direction
        # the same throw as the still draw, but for the swings before its release
        assert th.t_release == pytest.approx(st.t_release + th.back_time + th.forward_time)
        for f in ("p_release", "v_release", "aim", "flight_time", "hand_amp"):
            np.testing.assert_array_equal(getattr(th, f), getattr(st, f))
        # the path: the forward swing starts at rest and speeds up to the release
        t = np.linspace(-th.forward_time, 0.0, 200)
        p, v = ball_states(th, t)
        s = np.linalg.norm(v, axis=1)
        assert np.all(np.diff(s[:-1]) >= -1e-9) and s[0] < 1e-9
        np.testing.assert_allclose(p[0], th.p_release - th.forward_swing, atol=1e-12)


def test_back_swing_ends_at_rest_and_the_hold_before_it_is_only_hand_motion(windups):
    for th in windups[:20]:
        t_b, t_f = _phases(th)
        _, v = ball_states(th, np.array([t_b, t_f]))
        assert np.abs(v).max() < 0.1  # hand motion (about 4 cm/s) at its start, 0 at its end
        assert np.abs(v[1]).max() < 1e-9
        p, _ = ball_states(th, np.linspace(-th.t_release, t_b, 50))
        hold = th.p_release - th.forward_swing - th.back_swing
        assert np.abs(p - hold).max() <= 2 * CFG.hand_motion


def test_a_feint_never_crosses_the_plane_and_ends_at_rest(feints, stills):
    for th, st in zip(feints, stills[: len(feints)], strict=True):
        assert th.kind == "feint" and np.all(th.v_release == 0.0)
        with pytest.raises(NoSolutionError, match="feint"):
            plane_crossing(th)
        t = np.linspace(-th.t_release, th.rest_time, 3000)
        p, v = ball_states(th, t)
        assert p[:, 0].min() > th.plane_x + 4.0
        after = t >= 0.0
        assert np.all(v[after] == 0.0) and np.all(p[after] == th.p_release)
        # its peak speed is the configured share of the throw it feigned
        t = np.linspace(-th.forward_time, 0.0, 2001)
        peak = np.linalg.norm(ball_states(th, t)[1], axis=1).max()
        ratio = peak / np.linalg.norm(st.v_release)
        lo, hi = TC.feint_peak_speed
        assert lo - 1e-4 <= ratio <= hi + 1e-4, th.id
        assert peak == pytest.approx(
            MINJERK_PEAK * np.linalg.norm(th.forward_swing) / th.forward_time
        )
        assert TC.feint_rest[0] <= th.rest_time <= TC.feint_rest[1]


def test_the_camera_sees_the_swing_and_a_feint_until_its_rest_ends(windups, feints):
    cam, ext = CameraModelConfig(), CameraExtrinsic()
    th = windups[0]
    dets = observe(th, cam, ext, np.random.default_rng(1))
    swing = [d for d in dets if -th.forward_time - th.back_time < d.capture_stamp < 0.0]
    assert len(swing) >= 0.7 * (th.forward_time + th.back_time) * cam.rate
    true = np.array([d.true_position_base for d in swing])
    assert np.ptp(true[:, 0]) > 0.5  # the ball travels about a metre on camera
    f = feints[0]
    last = observe(f, cam, ext, np.random.default_rng(1))[-1]
    assert f.rest_time - 2.0 / cam.rate < last.capture_stamp <= f.rest_time


def test_mixes_draw_kinds_in_proportion_and_feints_are_appended():
    ts = sample_throws(_cfg(parse_mix("still=0.5,windup=0.5")), 120, seed=2, feints=5)
    kinds = [t.kind for t in ts]
    assert 40 <= kinds[:120].count("windup") <= 80 and "feint" not in kinds[:120]  # 3.6 sigma
    assert kinds[120:] == ["feint"] * 5
    assert [t.id for t in ts[120:]] == [f"s2-f{j}" for j in range(5)]
    again = sample_throws(_cfg((0.3, 0.3, 0.4)), 3, seed=2, feints=5)
    np.testing.assert_array_equal(again[3].p_release, ts[120].p_release)  # independent of n


def test_parse_mix_reads_weights_and_refuses_nonsense():
    assert parse_mix("still=0.5,windup=0.5") == (0.5, 0.5, 0.0)
    assert parse_mix(" feint = 1 ") == (0.0, 0.0, 1.0)
    for bad in ("throw=1", "still=x", "still=-1", "still=0", ""):
        with pytest.raises(ConfigError, match="--mix"):
            parse_mix(bad)
    with pytest.raises(ConfigError, match="thrower.back_time"):
        ThrowerConfig(back_time=(0.4, 0.2))


def test_all_still_sets_are_bit_identical_to_those_of_the_code_before_the_thrower_model():
    """Fixture: throw set and ball states written by commit cd9b2c4 (tests/data/)."""
    old = load_throw_set(DATA / "throws_v1_seed7.json")
    assert old.config == _cfg(STILL_MIX)  # a version 1 set is all still holds
    new = sample_throws(old.config, 12, seed=7)
    states = json.loads((DATA / "throws_v1_seed7_states.json").read_text())["states"]
    for a, b, rec in zip(old.throws, new, states, strict=True):
        assert a.kind == "still"
        for f in a._fields:
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
        p, v = ball_states(b, np.array(rec["t"]))
        assert np.array_equal(p, rec["p"]) and np.array_equal(v, rec["v"])


def test_version_2_round_trip_keeps_every_kind_bit_exact(tmp_path, windups, feints, stills):
    mixed = [stills[0], windups[0], feints[0], windups[1]]
    path = tmp_path / "set.json"
    save_throw_set(path, mixed, CFG)
    doc = json.loads(path.read_text())
    assert doc["version"] == 2 and [r["kind"] for r in doc["throws"]][:3] == list(
        ("still", "windup", "feint")
    )
    assert "back_swing" not in doc["throws"][0]  # a still record has no swing
    for a, b in zip(mixed, load_throw_set(path).throws, strict=True):
        for f in a._fields:
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"kind": "lob"}, "kind 'lob'"),
        ({"forward_swing": [0.1, 0.0, 0.0]}, "mean speed"),
        ({"back_time": 0.0}, "back_time"),
        ({"forward_swing": [1.0]}, "forward_swing"),
    ],
)
def test_bad_swing_records_are_refused_naming_file_and_throw(tmp_path, windups, change, message):
    path = tmp_path / "bad.json"
    save_throw_set(path, windups[:2], CFG)
    doc = json.loads(path.read_text())
    doc["throws"][1].update(change)
    path.write_text(json.dumps(doc))
    with pytest.raises(ThinkfastError, match=rf"bad.json: throws\[1\].*{message}"):
        load_throw_set(path)


def test_a_version_1_file_with_kinds_is_refused(tmp_path, windups):
    path = tmp_path / "v1.json"
    save_throw_set(path, windups[:1], CFG)
    doc = json.loads(path.read_text())
    doc["version"] = 1
    path.write_text(json.dumps(doc))
    with pytest.raises(ThinkfastError, match="version 1 record has no kind"):
        load_throw_set(path)


def test_throws_command_writes_the_mix_and_refuses_a_bad_one(tmp_path):
    out = tmp_path / "set.json"
    proc = run_cli("thinkfast-sim", "throws", "-o", str(out), "--throws", "6", "--seed", "4",
                   "--mix", "still=0.5,windup=0.5", "--feints", "2")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    ts = load_throw_set(out)
    assert ts.config.thrower.mix == (0.5, 0.5, 0.0)
    assert [t.kind for t in ts.throws[6:]] == ["feint", "feint"]
    assert {t.kind for t in ts.throws[:6]} <= {"still", "windup"}
    assert_one_line_error(
        run_cli("thinkfast-sim", "throws", "-o", str(out), "--mix", "curve=1"), "--mix"
    )


def test_infeasible_forward_swing_ranges_fail_with_the_keys_named():
    tight = dataclasses.replace(
        TC, mix=(0.0, 1.0, 0.0), forward_time=(0.1, 0.1), forward_distance=(3.0, 3.0)
    )
    with pytest.raises(NoSolutionError, match="forward_time, forward_distance"):
        sample_throws(dataclasses.replace(CFG, thrower=tight), 1, seed=1)
