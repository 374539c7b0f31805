"""Simulated ABB controller: servo model in lockstep, and the EGM loop over UDP on loopback."""

import math

import numpy as np

from thinkfast.config import from_dict
from thinkfast.contract import egm
from thinkfast.sim.controller import ServoConfig, SimController

CFG = ServoConfig()
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
    assert cfg.delay == 0.03 and cfg.v_max == CFG.v_max
