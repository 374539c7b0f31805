"""Fault campaign (bench/faults.py): its parts, and a fast subset of its scenarios against the
real daemon.

The parts: the campaign's own EGM schema agrees with the daemon's wire format, every hostile
input it sends is one the contract refuses, the fault controller keeps its clock through faults,
and the checker catches what it must. The scenarios run ``thinkfast-run`` for real (quick mode).
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from bench.faultkit import rows as R
from bench.faultkit.checker import ReplyChecker
from bench.faultkit.controller import FaultController
from bench.faultkit.egm_pb import EgmRobot, decode_reply, robot_message
from bench.faultkit.fuzz import KINDS
from bench.faultkit.probe import stalls_near
from bench.faultkit.senders import MALFORMED_KINDS
from thinkfast.contract import egm

DT = 0.004


def test_campaign_schema_and_daemon_codec_agree_on_the_wire():
    """ABB's field numbers in the campaign's schema; the daemon decodes its EgmRobot, and the
    checker decodes the daemon's hand-written EgmSensor bytes to the same radians."""
    fields = {f.name: f.number for f in EgmRobot.DESCRIPTOR.fields}
    assert fields == {"header": 1, "feedBack": 2, "planned": 3, "motorState": 4, "mciState": 5,
                      "mciConvergenceMet": 6, "testSignals": 7, "rapidExecState": 8,
                      "measuredForce": 9, "utilizationRate": 10}  # fmt: skip
    q = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
    fb = egm.decode_robot(robot_message(7, 1234, q, unix_time=time.time()))
    assert (fb.seqno, fb.tm_ms, fb.motors_on, fb.mci_running) == (7, 1234, True, True)
    np.testing.assert_allclose(fb.q_rad, q, rtol=1e-15)
    rep = decode_reply(egm.encode_sensor(3, 99, q, -q))
    assert (rep.seqno, rep.tm, rep.mtype) == (3, 99, egm.MSGTYPE_CORRECTION)
    np.testing.assert_allclose(rep.q, q, rtol=1e-15)
    np.testing.assert_allclose(rep.qd, -q, rtol=1e-15)
    assert decode_reply(b"\xff\x00garbage") is None


@pytest.mark.parametrize("kind", sorted(MALFORMED_KINDS))
def test_every_malformed_datagram_is_refused_by_the_daemon_decoder(kind):
    rng = np.random.default_rng(0)
    with pytest.raises(egm.EgmDecodeError):
        egm.decode_robot(MALFORMED_KINDS[kind](rng, robot_message(1, 4, np.zeros(6))))


def test_there_are_at_least_40_fuzz_kinds_with_1_mb_payloads():
    assert len(KINDS) >= 40
    assert len(KINDS["mb_random"](np.random.default_rng(1), 0.0)) >= 1 << 20


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_fuzz_kind_breaks_the_detection_contract(kind):
    """The contract's intake refuses or drops the payload (never accepts it)."""
    from thinkfast.contract.detection import DetectionLimits
    from thinkfast.contract.frames import CameraExtrinsic
    from thinkfast.control.intake import Intake

    intake = Intake(CameraExtrinsic(), DetectionLimits())
    now = time.time()
    assert intake.take(KINDS[kind](np.random.default_rng(1), now), now) is None


class _EchoSensor:
    """A minimal EGM sensor (the daemon's codec): commands the fed-back joints plus ``offset``."""

    def __init__(self, offset):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.offset, self.packets, self.stop = np.asarray(offset), [], threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            fb = egm.decode_robot(data)
            self.packets.append(fb)
            self.sock.sendto(egm.encode_sensor(1, 0, fb.q_rad + self.offset, np.zeros(6)),
                             addr)  # fmt: skip

    def close(self):
        self.stop.set()
        self.thread.join(1)
        self.sock.close()


@pytest.mark.realtime
def test_fault_controller_keeps_its_clock_through_gaps_duplicates_resets_and_freezes():
    sensor = _EchoSensor(offset=np.full(6, 0.05))  # the command always runs 0.05 rad ahead
    ctl = FaultController(sensor.sock.getsockname(), seed=3).start()
    try:
        time.sleep(0.3)
        ctl.gap(0.1)
        time.sleep(0.3)
        ctl.duplicate = True
        time.sleep(0.1)
        ctl.duplicate = False
        ctl.reset_seqno()
        time.sleep(0.1)
        ctl.freeze(0.2)
        time.sleep(0.15)
        q_frozen = [p.q_rad for p in sensor.packets[-10:]]
        time.sleep(0.3)
    finally:
        ctl.stop()
        sensor.close()
    rows = ctl.rows.take()
    assert np.all(np.diff(rows[:, R.TM]) == 4 * np.diff(rows[:, R.K]))  # tm follows the grid
    silence = np.flatnonzero(rows[:, R.FLAGS].astype(int) & R.SILENCE)
    assert len(silence) == 1 and 95 <= 4 * (rows[silence[0], R.K] - rows[silence[0] - 1, R.K]) < 140
    assert (rows[:, R.FLAGS].astype(int) & R.DUP).sum() >= 20
    reset = np.flatnonzero(rows[:, R.FLAGS].astype(int) & R.SEQ_RESET)[0]
    assert rows[reset, R.SEQNO] == 0 and rows[reset, R.TM] > rows[reset - 1, R.TM]
    assert np.all(np.diff(rows[:reset, R.SEQNO]) == np.diff(rows[:reset, R.K]))  # counts cycles
    assert np.ptp(np.array(q_frozen), axis=0).max() == 0.0  # the arm stood while frozen
    moved = rows[-1, R.Q_TRUE] - rows[0, R.Q_TRUE]
    assert np.all(moved > 0.5)  # and it follows the commands again (~0.05 rad per 0.05 s)


@pytest.mark.realtime
def test_a_jittering_fault_controller_stamps_tm_unevenly_and_its_pauses_stop_its_servo():
    """Jitter mode: ``tm`` off the 4 ms grid and repeating, ``seqno`` and the cycle +1 per
    packet (never skipped, also when this host stalls the loop), and after a pause ``tm`` has
    jumped by it while the servo moved one cycle."""
    from thinkfast.sim.controller import ClockJitter

    sensor = _EchoSensor(offset=np.full(6, 0.05))
    ctl = FaultController(sensor.sock.getsockname(), seed=3).start()
    try:
        ctl.jitter(ClockJitter(repeat=0.3, seed=2))
        time.sleep(0.3)
        ctl.gap(0.06, R.PAUSE)
        time.sleep(0.3)
    finally:
        ctl.stop()
        sensor.close()
    rows = ctl.rows.take()
    rows = rows[np.flatnonzero(np.diff(rows[:, R.K]) == 1)[0] + 5 :]  # jitter mode on
    d_tm, paused = np.diff(rows[:, R.TM]), (rows[1:, R.FLAGS].astype(int) & R.PAUSE) > 0
    assert np.all(np.diff(rows[:, R.K]) == 1) and np.all(np.diff(rows[:, R.SEQNO]) == 1)
    p = int(np.flatnonzero(paused)[0]) + 1  # the row after the pause (stamps may repeat)
    after = rows[min(p + 5, len(rows) - 1), R.TM] - rows[p - 1, R.TM]
    assert paused.sum() == 1 and after >= 55
    late = (rows[1:, R.FLAGS].astype(int) & R.LATE) > 0  # this host stalled the loop: a jump
    ordinary = ~(paused | late | np.r_[False, paused[:-1]])
    assert (d_tm[ordinary] == 0).any() and (d_tm[ordinary] % 4 != 0).any()  # off the 4 ms grid
    assert (d_tm >= 0).all()
    assert {3, 5} <= set(d_tm.tolist())


def _rows(q, qd=None, k=None, replied=None, q_true=None, qd_true=None):
    n = len(q)
    k = np.arange(n) if k is None else np.asarray(k)
    out = np.zeros((n, R.NCOL))
    out[:, R.K], out[:, R.T_SEND] = k, 1000.0 + DT * k
    out[:, R.N_VALID] = 1 if replied is None else replied
    out[:, R.CMD_Q] = q
    out[:, R.CMD_QD] = np.gradient(q, DT, axis=0) if qd is None else qd
    out[:, R.Q_TRUE] = q if q_true is None else q_true
    out[:, R.QD_TRUE] = out[:, R.CMD_QD] if qd_true is None else qd_true
    out[out[:, R.N_VALID] == 0, R.CMD_Q] = np.nan
    return out


def test_checker_passes_a_smooth_motion_and_flags_jumps_and_jerky_brakes(robot):
    t = DT * np.arange(300)
    smooth = robot.home + np.outer(0.2 * (1 - np.cos(2.0 * t)), np.ones(6))
    ok = ReplyChecker(robot)
    ok.feed(_rows(smooth[:150]))
    ok.feed(_rows(smooth[150:], k=np.arange(150, 300)))  # in two batches
    assert ok.failures() == [] and 0.1 < ok.f["v_ratio"] < 1 and 0.01 < ok.f["a_ratio"] < 1
    jump = smooth.copy()
    jump[200:, 0] += 0.02  # 20 mrad in one cycle: 5 rad/s, far beyond v_max
    bad = ReplyChecker(robot)
    bad.feed(_rows(jump))
    assert any("velocity" in f for f in bad.failures()) and bad.f["v_ratio"] > 1.5
    held = _rows(jump, replied=(np.arange(300) < 199) | (np.arange(300) > 200))
    excused = ReplyChecker(robot)  # the jump comes after missed replies: counted in *_all only
    excused.feed(held)
    assert excused.f["v_ratio"] < 1 < excused.f["v_ratio_all"] and excused.n["missed"] == 2
    braking = ReplyChecker(robot)  # a brake that steps the acceleration at once: jerk 6 j_max
    v = np.r_[np.linspace(0, 1.2, 101), np.full(100, 1.2), np.linspace(1.2, 0.0, 101)[1:]]
    q = robot.home + np.outer(np.cumsum(v) * DT, np.ones(6))
    braking.feed(_rows(q, qd=np.outer(v, np.ones(6))), lambda rows: rows[:, R.K] >= 200)
    assert braking.f["speedref_jerk_ratio_brake"] > 5 and braking.failures()


def test_checker_wants_the_first_command_after_a_silence_at_the_measured_state(robot):
    q = np.tile(robot.home, (40, 1))
    k = np.r_[np.arange(20), 100 + np.arange(20)]  # 320 ms of silence after cycle 19
    q_true = q.copy()
    q_true[20:, 1] += 0.1  # the arm drifted 0.1 rad meanwhile (measured)
    stale = ReplyChecker(robot)
    stale.feed(_rows(q, k=k, q_true=q_true, qd=np.zeros((40, 6)), qd_true=np.zeros((40, 6))))
    assert stale.n["resyncs_checked"] == 2 and stale.f["resync_pos_err_mrad"] > 99
    follows = q.copy()
    follows[20:] = q_true[20:]
    good = ReplyChecker(robot)
    good.feed(_rows(follows, k=k, q_true=q_true, qd=np.zeros((40, 6)), qd_true=np.zeros((40, 6))))
    assert good.f["resync_pos_err_mrad"] == 0.0 and not good.resync_fail


@pytest.mark.parametrize("unanswered", [1, 2, 3])
def test_checker_excuses_two_unanswered_cycles_after_a_silence_and_counts_a_third(
    robot, unanswered
):
    """The daemon leaves the first two packets after a silence unanswered (it measures the
    velocity from three): by design, not missed replies; a third one is missed as usual. The
    first reply is still checked against the measured state."""
    n = 40
    q = np.tile(robot.home, (n, 1))
    k = np.r_[np.arange(20), 100 + np.arange(20)]  # 320 ms of silence after cycle 19
    replied = np.ones(n, dtype=int)
    replied[20 : 20 + unanswered] = 0
    checker = ReplyChecker(robot)
    checker.feed(_rows(q, k=k, qd=np.zeros((n, 6)), replied=replied))
    excused = min(unanswered, 2)
    assert checker.n["missed_after_silence"] == excused
    missed = unanswered - excused
    assert checker.n["missed"] == missed and len(checker.missed_times) == missed
    assert checker.n["cycles"] == n - excused and checker.n["resyncs_checked"] == 2
    answered = 100.0 * (n - unanswered) / (n - excused)
    assert checker.summary()["answered_pct"] == pytest.approx(answered)
    assert checker.failures() == []


@pytest.mark.parametrize("late", [False, True])
def test_a_restart_answering_the_packet_before_is_excused_only_after_a_missed_cycle(robot, late):
    """An arm coasting at 0.3 rad/s after a silence; the restart commands the state measured in
    one packet. On time (the third packet's cycle) it must be that cycle's state: one cycle
    behind is 1.2 mrad off and fails. Arrived a cycle late (a host stall, the third cycle
    missed) the same command answers the packet before: counted in ``resyncs_late``, passed."""
    n, speed = 40, 0.3
    k = np.r_[np.arange(20), 100 + np.arange(20)]  # 320 ms of silence after cycle 19
    q_true = np.tile(robot.home, (n, 1))
    q_true[20:, 0] += 0.05 + speed * DT * np.arange(20)  # coasting, measured
    qd_true = np.zeros((n, 6))
    qd_true[20:, 0] = speed
    first = 23 if late else 22  # the first answered cycle after the silence
    q = q_true.copy()
    q[first] = q_true[first - 1]  # the command: the state of the packet before
    replied = np.ones(n, dtype=int)
    replied[20:first] = 0
    checker = ReplyChecker(robot)
    checker.feed(_rows(q, k=k, q_true=q_true, qd=qd_true, qd_true=qd_true, replied=replied))
    assert checker.n["resyncs_checked"] == 2
    if late:
        assert checker.n["resyncs_late"] == 1 and not checker.resync_fail
        assert checker.n["missed"] == 1  # the late cycle itself still counts as missed
    else:
        assert checker.n["resyncs_late"] == 0
        assert checker.resync_fail and checker.f["resync_pos_err_mrad"] == pytest.approx(1.2)


@pytest.mark.parametrize("batches", [1, 2])
def test_replies_beyond_the_requests_sent_are_extra_and_a_late_first_reply_is_not(robot, batches):
    """The first reply may arrive a cycle late, in the cycle of the second packet with that
    packet's own reply: two replies for two packets, none extra (the count starts before the
    first reply). A cycle with two replies that follows no unanswered one is one extra reply (a
    daemon answering something the controller never sent as a request)."""
    n = 40
    q = np.tile(robot.home, (n, 1))
    late_first = np.ones(n, dtype=int)
    late_first[0], late_first[1] = 0, 2
    extra = np.ones(n, dtype=int)
    extra[30] = 2
    for replied, want in ((late_first, 0), (extra, 1)):
        rows = _rows(q, qd=np.zeros((n, 6)), replied=replied)
        checker = ReplyChecker(robot)
        for part in np.array_split(rows, batches):
            checker.feed(part)
        assert checker.n["extra_replies"] == want


def test_stalls_near_attributes_events_to_overlapping_stalls():
    stalls = np.array([[10.0, 0.005], [20.0, 0.1]])
    got = stalls_near(np.array([9.997, 10.02, 20.05, 30.0]), stalls, 0.006, 0.004)
    assert got.tolist() == [True, False, True, False]


# ---------------------------------------------------------------------- the real daemon
@pytest.fixture(scope="module")
def campaign_ctx(tmp_path_factory):
    from bench.faultkit.campaign import make_context
    from tests.conftest import compile_small_tree

    tree = compile_small_tree(tmp_path_factory.mktemp("faults"), spacing=0.3)
    return make_context(tree, seed=1, log=lambda m: None)


@pytest.mark.realtime
@pytest.mark.parametrize(
    "name",
    ["malformed", "duplicated", "second_sender", "sigterm", "silence_rest", "record_missing"],
)
def test_scenario_passes_against_the_real_daemon(campaign_ctx, name):
    """The scenario's checks (see bench/faults.py --list) hold for thinkfast-run, quick mode."""
    from bench.faultkit.scenario import REGISTRY, Options

    result = REGISTRY[name][0](campaign_ctx, Options(quick=True))
    assert result.passed is not None, result.failures  # the harness itself ran
    assert result.passed, result.failures
