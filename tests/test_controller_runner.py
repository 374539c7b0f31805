"""The simulated controller on real UDP: one exchange per cycle, misses and garbage counted,
late replies told apart by their kernel arrival stamp (the servo model: test_sim_controller.py)."""

import socket
import threading
import time

import numpy as np
import pytest

from thinkfast.contract import egm
from thinkfast.link.egm_server import EgmServer
from thinkfast.sim.controller import ServoConfig, SimController
from thinkfast.sim.controller_runner import ControllerRunner

DT = ServoConfig().dt


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
def _udp_sensor(answer):
    """A sensor socket on loopback whose thread calls ``answer(sock, data, addr)`` for every
    datagram; returns (address, stop): ``stop()`` ends the thread and closes the socket."""
    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind(("127.0.0.1", 0))
    sensor.settimeout(0.5)
    done = threading.Event()

    def loop():
        while not done.is_set():
            try:
                data, addr = sensor.recvfrom(65535)
            except OSError:
                continue
            answer(sensor, data, addr)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()

    def stop() -> None:
        done.set()
        thread.join(1.0)
        sensor.close()

    return sensor.getsockname(), stop


@pytest.mark.realtime
def test_silent_or_garbage_sensor_counts_missed_and_malformed_and_the_arm_holds():
    k = [0]

    def garbage(sock, _data, addr):  # every other request: bytes that are not an EgmSensor
        k[0] += 1
        if k[0] % 2:
            sock.sendto(b"\x0a\x02junk", addr)

    address, stop = _udp_sensor(garbage)
    sim = SimController(q0=np.full(6, 0.1))
    runner = ControllerRunner(sim, address, rate_hz=0, n=20, reply_timeout=0.002)
    runner.run()
    runner.join()
    stop()
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


class _Stalling(SimController):
    """A servo model whose every 25th step stalls 30 ms (a loaded host, this side)."""

    def step(self, dt):
        super().step(dt)
        if self.seqno % 25 == 0:
            time.sleep(0.03)


@pytest.mark.realtime
@pytest.mark.parametrize("keep_cycle", [True, False])
def test_an_overrunning_controller_keeps_its_cycle_only_when_asked(keep_cycle):
    """keep_cycle: the cycles this side could not serve are stepped through unsent, so the
    sequence numbers stay the wall clock (seqno x dt), as thinkfast-calib dynamics reads them;
    without it the model's time falls behind by the stalls."""
    server, stop, thread = _hold_server(np.zeros(6))
    sim = _Stalling()
    runner = ControllerRunner(sim, server.address, keep_cycle=keep_cycle).start()
    t0 = time.perf_counter()
    time.sleep(2.0)
    runner.stop()
    elapsed = time.perf_counter() - t0
    runner.join(2.0)
    stop.set()
    thread.join(1.0)
    server.close()
    st = runner.stats
    assert st.sent > 50  # it ran (how many cycles it served depends on the host)
    assert sim.seqno == st.sent + st.skipped
    if keep_cycle:  # at least the 30 ms stalls (7 cycles each), whatever else the host adds
        assert st.skipped >= 6 * (st.sent // 25)
        assert sim.seqno * DT == pytest.approx(elapsed, rel=0.1, abs=0.02)
    else:
        assert st.skipped == 0 and sim.seqno * DT < elapsed - 0.015 * (st.sent // 25)


@pytest.mark.realtime
def test_answers_count_late_or_not_in_answered():
    """``answered`` counts every well-formed answer applied, in its cycle (``replies``) or read
    at a later cycle (``late``): the sensor is alive however late it is (the simulated IRC5's
    comm timeout and the simulators' watchdog count these)."""

    def slow(sock, data, addr):  # every answer 3 ms after its request: after the 1 ms wait
        fb = egm.decode_robot(data)
        time.sleep(0.003)
        sock.sendto(egm.encode_sensor(fb.seqno, fb.tm_ms or 0, fb.q_rad, [0.0] * 6), addr)

    address, stop = _udp_sensor(slow)
    sim = SimController(q0=np.full(6, 0.1))
    runner = ControllerRunner(sim, address, rate_hz=100, n=60, reply_timeout=0.001)
    runner.run()
    stop()
    st = runner.stats
    assert st.late > 0 and st.malformed == 0
    assert st.answered == st.replies + st.late
