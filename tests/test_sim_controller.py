"""Simulated ABB controller: servo model in lockstep, and the EGM loop over UDP on loopback."""

import math
import socket
import threading

import numpy as np
import pytest

from thinkfast.config import from_dict
from thinkfast.contract import egm
from thinkfast.daemon.egm_server import EgmServer
from thinkfast.sim.controller import ControllerRunner, ServoConfig, SimController

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


def _hold_server(target):
    def reply(fb, before=None):  # a sensor commanding a constant target at zero speed
        return target, np.zeros(6)

    server = EgmServer("127.0.0.1:0", reply)
    stop = threading.Event()
    thread = threading.Thread(target=server.serve, args=(stop, 0.01), daemon=True)
    thread.start()
    return server, stop, thread


@pytest.mark.realtime
@pytest.mark.parametrize("rate_hz, n", [(250.0, 150), (0.0, 2000)])
def test_udp_loop_on_loopback_accounts_for_every_cycle_and_moves_the_arm(rate_hz, n):
    target = np.array([0.3, -0.2, 0.1, 0.5, -0.5, 1.0])
    server, stop, thread = _hold_server(target)
    sim = SimController()
    runner = ControllerRunner(sim, server.address, rate_hz=rate_hz, n=n).start()
    runner.join(timeout=10.0)
    stop.set()
    thread.join(1.0)
    server.close()
    st = runner.stats
    assert st.sent == n and st.malformed == 0
    # every request is answered or counted missed (how many in time depends on the host's
    # load: bench/wallclock.py measures it)
    assert st.replies + st.missed == n and st.replies > 0
    c = server.counters
    # Every request is answered, except one the server found already out of date because the
    # controller (timed out on a loaded machine) had sent a newer one: that one is a miss too.
    assert c.received == n and c.replied + c.superseded == c.received >= st.replies
    assert c.superseded <= st.missed and c.deferred == c.reply_errors == 0
    assert len(st.rtt_s) == st.replies and min(st.rtt_s) > 0.0  # latency: bench/egm_latency.py
    h = sim.history()
    assert len(h.t) == n + 1 and h.t[-1] == pytest.approx(n * DT)
    np.testing.assert_allclose(h.q[-1], target, atol=0.01)  # 150 ticks = 0.6 s: settled


@pytest.mark.realtime
def test_silent_or_garbage_sensor_counts_missed_and_malformed_and_the_arm_holds():
    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind(("127.0.0.1", 0))
    sensor.settimeout(0.5)
    stop = threading.Event()

    def garbage():  # answers every other request with bytes that are not an EgmSensor
        k = 0
        while not stop.is_set():
            try:
                _, addr = sensor.recvfrom(65535)
            except OSError:
                continue
            k += 1
            if k % 2:
                sensor.sendto(b"\x0a\x02junk", addr)

    thread = threading.Thread(target=garbage, daemon=True)
    thread.start()
    sim = SimController(q0=np.full(6, 0.1))
    runner = ControllerRunner(sim, sensor.getsockname(), rate_hz=0, n=20, reply_timeout=0.002)
    runner.run()
    runner.join()
    stop.set()
    thread.join(1.0)
    sensor.close()
    st = runner.stats
    assert (st.sent, st.replies, st.missed) == (20, 0, 20)
    assert st.malformed == sim.malformed == 10
    np.testing.assert_array_equal(sim.history().q[-1], np.full(6, 0.1))


@pytest.mark.realtime
def test_a_hot_controller_sends_on_its_cycle_and_spins_for_the_replies():
    """lead/spin: the sends keep the 4 ms cycle (busy-waited, not slept to) and the replies of a
    sensor in another process (no shared GIL) are received and counted (how many arrive in time
    depends on the host's load: bench/wallclock.py measures it)."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    bench = Path(__file__).resolve().parents[1] / "bench" / "egm_latency.py"
    proc = subprocess.Popen(
        [sys.executable, str(bench), "--serve", "127.0.0.1:0"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = int(proc.stdout.readline().split()[1])
        sends = []

        class Timed(SimController):
            def robot_message(self):
                sends.append(time.perf_counter())
                return super().robot_message()

        runner = ControllerRunner(
            Timed(), ("127.0.0.1", port), rate_hz=250.0, n=200, spin=0.001, lead=0.001
        )
        runner.run()
        runner.join()
    finally:
        proc.stdin.close()
        proc.wait(5)
    st = runner.stats
    assert st.sent == 200 and st.replies + st.missed == 200 and st.replies > 0
    # the cycle is kept on average: 199 cycles never pass in less than 199 x 4 ms less the
    # lead (the jitter of single sends is measured by bench/wallclock.py, not asserted here)
    assert sends[-1] - sends[0] >= (len(sends) - 1) * DT - 0.001


@pytest.mark.realtime
@pytest.mark.parametrize("deadline_offset, in_time", [(1.0, 1), (-1.0, 0)])
def test_a_missed_reply_that_had_arrived_in_time_is_told_apart(deadline_offset, in_time):
    """in_time_unread: the kernel's arrival stamp of a late reply against the missed cycle's
    deadline (the measuring side was stalled, not the sensor)."""
    import time

    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind(("127.0.0.1", 0))
    runner = ControllerRunner(SimController(), sensor.getsockname(), rate_hz=0, n=1)
    sensor.sendto(egm.encode_sensor(1, 0, np.zeros(6), np.zeros(6)), runner.address)
    time.sleep(0.01)  # queued: the reply to a cycle this side missed
    runner._miss_deadline = time.perf_counter() + deadline_offset
    runner.run()  # reads it as late, then one cycle the silent sensor misses
    runner.join()
    sensor.close()
    st = runner.stats
    assert (st.late, st.missed, st.in_time_unread) == (1, 1, in_time)
