"""Simulated ABB controller: servo model in lockstep, and the EGM loop over UDP on loopback."""

import dataclasses
import math
import warnings

import numpy as np

from tests.conftest import ROBOT_TOML
from thinkfast.config import from_dict
from thinkfast.contract import egm
from thinkfast.robot.model import load_robot
from thinkfast.sim.controller import ServoConfig, SimController, servo_for

CFG = servo_for(load_robot(ROBOT_TOML))  # the default robot's limits
DT = CFG.dt
V_MAX, A_MAX = np.array(CFG.v_max), np.array(CFG.a_max)


def _run_lockstep(sim, ref, ticks):
    """Command ``ref(t) -> (q, qd)`` each tick, as a sensor answering at once would."""
    for _ in range(ticks):
        sim.command(*ref(sim.t))
        sim.step(DT)
    return sim.history()


def test_ramp_is_tracked_with_the_modelled_lag():
    speed = np.array([1.0, 0.5, -0.8, 2.0, -1.0, 3.0])

    def ramp(t):
        return speed * t, speed

    h = _run_lockstep(SimController(), ramp, 375)  # 1.5 s, inside every joint's range
    lag = CFG.delay + 1.0 / (2 * math.pi * CFG.lowpass_hz)  # ~16 ms
    late = h.t > 0.5
    err = h.q[late] - speed * (h.t[late, None] - lag)
    assert (np.abs(err) < 0.003 * np.abs(speed)).all()  # within 3 ms of the modelled lag
    np.testing.assert_allclose(h.qd[late], np.broadcast_to(speed, h.qd[late].shape), atol=1e-3)


def test_motion_starts_only_after_the_transport_delay():
    sim = SimController()
    sim.command(np.full(6, 0.5), np.zeros(6))
    n_quiet = int(round(CFG.delay / DT))
    for _ in range(n_quiet):
        sim.step(DT)
    assert not sim.history().q.any()
    sim.step(DT)
    assert (sim.q > 0).all()


def test_absurd_commands_are_bounded_by_the_arm_limits():
    rng = np.random.default_rng(7)

    def wild(t):
        return rng.uniform(-100, 100, 6), rng.uniform(-1e3, 1e3, 6)

    h = _run_lockstep(SimController(), wild, 750)
    assert (np.abs(h.qd) <= V_MAX + 1e-12).all()
    assert (np.abs(np.diff(h.qd, axis=0)) <= A_MAX * DT * (1 + 1e-9)).all()
    assert (h.q >= np.array(CFG.q_min)).all() and (h.q <= np.array(CFG.q_max)).all()


def test_same_inputs_give_the_same_history():
    def sine(t):
        return np.sin(3 * t) * np.ones(6), 3 * np.cos(3 * t) * np.ones(6)

    a = _run_lockstep(SimController(), sine, 200)
    b = _run_lockstep(SimController(), sine, 200)
    assert all((x == y).all() for x, y in zip(a, b, strict=True))


def test_messages_round_trip_through_the_protocol_core():
    sim = SimController(q0=np.full(6, 0.2))
    fb = egm.decode_robot(sim.robot_message())
    assert fb.seqno == 1 and fb.motors_on and fb.mci_running
    np.testing.assert_allclose(fb.q_rad, 0.2)
    assert sim.handle_sensor(egm.encode_sensor(1, 0, np.full(6, 0.3), np.zeros(6)))
    assert not sim.handle_sensor(b"\x00garbage") and sim.malformed == 1
    assert sim.commands().q.shape == (1, 6)


def test_servo_config_loads_from_a_toml_table():
    cfg = from_dict(ServoConfig, {"delay": 0.03, "kp": 10.0}, "sim.toml", "servo")
    assert cfg.delay == 0.03 and cfg.v_max == ()  # the robot's (servo_for)
    assert servo_for(load_robot(ROBOT_TOML), cfg).v_max == CFG.v_max


def test_the_servo_limits_are_the_robots_unless_given(tmp_path):
    """servo_for: the URDF's position limits and robot.toml's velocity and acceleration limits
    of the robot simulated; a limit the servo file gives wins; one of another length is refused
    naming the key. A bare SimController has the default robot's (the numbers it always had)."""
    import shutil

    import pytest

    from thinkfast.errors import ConfigError

    d = tmp_path / "robot"
    shutil.copytree(ROBOT_TOML.parent, d)
    toml = d / "robot.toml"
    toml.write_text(
        toml.read_text().replace("max_acceleration = [12.0,", "max_acceleration = [6.0,")
    )
    robot = load_robot(toml)
    servo = servo_for(robot)
    assert servo.a_max[0] == 6.0 and servo.q_max == tuple(robot.q_upper)
    assert servo.v_max == tuple(robot.v_max) and servo.q_min == tuple(robot.q_lower)
    assert servo_for(robot, ServoConfig(a_max=(1.0,) * 6)).a_max == (1.0,) * 6
    with pytest.raises(ConfigError, match="servo.toml: a_max: expected 6 values"):
        servo_for(robot, ServoConfig(a_max=(1.0,) * 5), "servo.toml")
    deg = math.pi / 180.0  # the numbers ServoConfig held before it took the robot's
    assert SimController().config.q_max == tuple(d * deg for d in (180, 120, 65, 200, 115, 400))
    assert SimController().config.a_max == (12.0, 12.0, 15.0, 30.0, 30.0, 40.0)


def _reference_step(sim, dt):
    """The array form of :meth:`SimController.step` as first written: the bit-exact reference."""
    cfg = sim.config
    n = max(1, math.ceil(dt / cfg.substep - 1e-9))
    h = dt / n
    alpha = 1.0 - math.exp(-2.0 * math.pi * cfg.lowpass_hz * h)
    q_min, q_max, v_max = (np.array(x) for x in (cfg.q_min, cfg.q_max, cfg.v_max))
    a = np.array(cfg.a_max)
    q, qd = sim.q.copy(), sim.qd.copy()
    fq, fqd = sim._filt
    if not sim.following:
        sim._queue.clear()
        sim._ref = (q + qd * np.abs(qd) / (2.0 * a), np.zeros(6))
        fq, fqd = sim._ref
    for i in range(n):
        t = sim.t + i * h
        while sim._queue and sim._queue[0][0] <= t + 1e-12:
            sim._ref = sim._queue.popleft()[1:]
        rq, rqd = sim._ref
        fq, fqd = fq + alpha * (rq - fq), fqd + alpha * (rqd - fqd)
        v_cmd = np.clip(cfg.kff * fqd + cfg.kp * (fq - q), -v_max, v_max)
        dv = np.clip((v_cmd - qd) * (h / cfg.tau_v), -a * h, a * h)
        up, dn = np.maximum(q_max - q, 0.0), np.maximum(q - q_min, 0.0)
        v_up = np.minimum(np.sqrt(a * up), up / h)
        v_dn = np.minimum(np.sqrt(a * dn), dn / h)
        qd = np.clip(qd + dv, np.maximum(-v_max, -v_dn), np.minimum(v_max, v_up))
        q = q + qd * h
        stop = (q < q_min) | (q > q_max)
        q, qd = np.clip(q, q_min, q_max), np.where(stop, 0.0, qd)
    sim._filt = (fq, fqd)
    sim.q, sim.qd, sim.t = q, qd, sim.t + dt
    sim._hist.append((sim.t, q.copy(), qd.copy()))


def _same_bits(a, b):
    """Equal arrays to the bit: values (NaN where NaN) and the sign of every zero."""
    a, b = np.asarray(a), np.asarray(b)
    return np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))


def _random_reference(rng, lo, hi):
    """A reference ``(q, qd)``: inside, near or beyond the limits; slow, fast or absurd speeds."""
    kind = rng.integers(5)
    if kind == 0:  # inside the range
        q = rng.uniform(lo, hi)
    elif kind == 1:  # beyond the limits
        q = rng.uniform(lo - 2.0, hi + 2.0)
    else:  # within a few mrad of a limit, either side
        q = np.where(rng.random(6) < 0.5, lo, hi) + rng.uniform(-3e-3, 3e-3, 6)
    qd = rng.uniform(-1.0, 1.0, 6) * 10.0 ** rng.integers(-2, 4)
    zeros = rng.random(6) < 0.1  # exact zeros of either sign
    qd[zeros] = np.where(rng.random(zeros.sum()) < 0.5, 0.0, -0.0)
    return q, qd


def _random_config(rng):
    if rng.random() < 0.5:
        return CFG
    return dataclasses.replace(
        CFG,
        delay=float(rng.choice([0.0, 0.003, 0.008, 0.02])),
        lowpass_hz=float(rng.uniform(2.0, 200.0)),
        kp=float(rng.uniform(0.0, 80.0)),
        kff=float(rng.uniform(0.0, 1.5)),
        tau_v=float(rng.uniform(0.0003, 0.05)),  # below a substep: overshoot
        substep=float(rng.choice([0.001, 0.0007, 0.004])),
        v_max=tuple(float(x) for x in rng.uniform(0.05, 4.0, 6)),
        a_max=tuple(float(x) for x in rng.uniform(0.5, 60.0, 6)),
    )


def _drive_twins(seed, ticks):
    """Run the same random commands and steps through ``step`` and the reference; compare."""
    rng = np.random.default_rng(seed)
    cfg = _random_config(rng)
    lo, hi = np.array(cfg.q_min), np.array(cfg.q_max)
    q0 = rng.uniform(lo, hi) if rng.random() < 0.7 else np.where(rng.random(6) < 0.5, lo, hi)
    new, ref = SimController(cfg, q0=q0), SimController(cfg, q0=q0)
    for _ in range(ticks):
        dt = float(rng.choice([cfg.dt, cfg.dt, rng.uniform(1e-4, 0.013), 0.0025, 1e-3]))
        if rng.random() < 0.05:  # toggle one of the conditions of following
            name = str(rng.choice(["motors_on", "mci_running", "rapid_running"]))
            for sim in (new, ref):
                setattr(sim, name, not getattr(sim, name))
        for _ in range(rng.choice([0, 1, 1, 1, 2, 3])):  # received anywhere within the step
            cmd, t_rx = _random_reference(rng, lo, hi), new.t + rng.uniform(-dt, dt)
            for sim in (new, ref):
                sim.command(*cmd, t=t_rx)
        new.step(dt)
        _reference_step(ref, dt)
        assert new.t == ref.t
        for x, y in zip((new.q, new.qd, *new._filt), (ref.q, ref.qd, *ref._filt), strict=True):
            assert _same_bits(x, y), (seed, x, y)
    assert all(_same_bits(x, y) for x, y in zip(new.history(), ref.history(), strict=True))
    return cfg, new.history()


def test_step_matches_the_array_form_to_the_bit():
    """Random commands, steps, limits and following phases: q, qd, filter, t, history equal."""
    clipped = limited = stopped = 0
    for seed in range(24):
        cfg, h = _drive_twins(seed, 120)
        clipped += int((np.abs(h.qd) >= np.array(cfg.v_max) * (1 - 1e-6)).sum())
        limited += int(((h.q == np.array(cfg.q_min)) | (h.q == np.array(cfg.q_max))).sum())
        stopped += int((h.qd[1:] == 0.0).sum())
    assert clipped and limited and stopped  # the clip, limit and stop branches were exercised


def test_step_matches_the_array_form_on_non_finite_and_odd_inputs():
    """NaN and inf references, a zero and a negative step, a zero or negative a_max."""
    rng = np.random.default_rng(11)
    odd = dataclasses.replace(CFG, a_max=(12.0, 0.0, -3.0, 30.0, 30.0, 40.0), v_max=(0.0,) * 6)
    for cfg in (CFG, odd):
        new, ref = SimController(cfg), SimController(cfg)
        for k in range(80):
            q, qd = _random_reference(rng, np.array(cfg.q_min), np.array(cfg.q_max))
            q[rng.integers(6)] = rng.choice([np.nan, np.inf, -np.inf, 1.0])
            qd[rng.integers(6)] = rng.choice([np.nan, np.inf, -np.inf, 1.0])
            dt = [CFG.dt, 0.0, -0.002, 0.0031][k % 4]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                for sim in (new, ref):
                    sim.command(q, qd)
                new.step(dt)
                _reference_step(ref, dt)
            for x, y in zip((new.q, new.qd, *new._filt), (ref.q, ref.qd, *ref._filt), strict=True):
                assert _same_bits(x, y)
        assert np.isnan(new.q).any()  # the non-finite inputs did reach the state
