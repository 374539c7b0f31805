"""Setpoints on the controller's clock: duplicates, missed cycles, silences, deviation faults.

The real executor (small compiled tree, real Ruckig) and the real supervisor, driven packet by
packet with controller stamps as a controller would send them.
"""

import math

import numpy as np
import pytest

from tests.conftest import compile_small_tree
from thinkfast.control.config import RunConfig
from thinkfast.control.core import ControlCore
from thinkfast.control.egm_clock import ControllerClock
from thinkfast.control.executor import FAULT, IDLE, RETURNING, Executor
from thinkfast.control.link import Feedback
from thinkfast.control.safety import SafetySupervisor, robot_limits
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.tree.file import load_tree

CFG = RunConfig()
DT = CFG.safety.dt
T0 = 1.7e9  # wall clock of the first packet [s]


@pytest.fixture(scope="module")
def rtree(tmp_path_factory, robot):
    path = compile_small_tree(tmp_path_factory.mktemp("ctl"), spacing=0.15)
    return runtime_tree(load_tree(path), robot, CFG)


def _control(rtree, robot, events=None):
    ex = Executor(rtree, robot, CFG, "naive")
    sup = SafetySupervisor(robot_limits(robot, CFG.safety.position_margin), CFG.safety, robot.home)
    on_event = (lambda t, k, d: events.append(k)) if events is not None else (lambda *a: None)
    return ControlCore(ex, sup, CFG.safety, on_event)


def _away(robot):
    """A start away from home: the executor returns home, so the plan moves."""
    return robot.home + np.array([0.6, -0.3, 0.3, 0.5, 0.3, -0.4])


def _assert_admissible_over_the_controller_clock(t, q, qd, robot, tol=1e-6):
    """Applied commands, one per controller cycle: finite differences within the limits."""
    t, q, qd = np.asarray(t), np.asarray(q), np.asarray(qd)
    dt = np.diff(t)[:, None]
    assert np.all(np.abs(np.diff(q, axis=0)) / dt <= robot.v_max * (1 + tol) + 1e-9)
    assert np.all(np.abs(qd) <= robot.v_max * (1 + tol))
    assert np.all(np.abs(np.diff(qd, axis=0)) / dt <= robot.a_max * (1 + tol))


def test_a_duplicated_packet_gets_the_same_setpoint_and_time_does_not_advance(rtree, robot):
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(1000, _away(robot)), T0)
    t, q, qd = [], [], []
    for k in range(1, 200):
        tm = 1000 + 4 * k
        r = ctl.on_feedback(Feedback(tm, ctl.sup.q), T0 + 0.004 * k)
        again = ctl.on_feedback(
            Feedback(tm, ctl.sup.q), T0 + 0.004 * k + 0.0003
        )  # the same EgmRobot
        assert again.q is r.q and again.qd is r.qd and again.tick.repeat
        t.append(tm / 1000), q.append(r.q), qd.append(r.qd)
    assert ctl.repeats == 199 and ctl.sup.ticks == 199  # one supervisor tick per cycle
    assert np.ptp(np.array(q), axis=0).max() > 0.2  # the arm really moved
    _assert_admissible_over_the_controller_clock(t, q, qd, robot)


def _applied(t, q, qd, dt=DT):
    """What the controller applies each cycle: the last reply, kept over cycles without one."""
    k = np.round((np.asarray(t) - t[0]) / dt).astype(int)
    idx = np.searchsorted(k, np.arange(k[-1] + 1), side="right") - 1
    return np.asarray(q)[idx], np.asarray(qd)[idx]


def test_missed_cycles_the_reply_moves_on_one_cycle_from_the_reference_the_controller_held(
    rtree, robot
):
    """The controller got no reply for some cycles and kept the last reference: the next reply
    moves one cycle on from it (never two cycles' motion in one), and the executor plans on
    from it. Over the controller's clock the applied positions move within ``v_max`` and
    ``speedRef`` changes within ``a_max``, holds included (before: up to 3x ``v_max``)."""
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, _away(robot), 0), T0)
    rng = np.random.default_rng(4)
    tm, t, q, qd = 0, [0.0], [ctl.sup.q], [ctl.sup.qd]
    for _ in range(150):
        tm += 4 * int(rng.choice([1, 1, 1, 2, 3]))  # skipped cycles
        r = ctl.on_feedback(Feedback(tm, ctl.sup.q, tm // 4), T0 + tm / 1000)
        t.append(tm / 1000), q.append(r.q), qd.append(r.qd)
    assert ctl.sup.ticks == 150 and ctl.held == tm // 4 - 150 and ctl.catch_ups > 0
    assert np.ptp(np.array(q), axis=0).max() > 0.2  # the arm really moved
    qa, qda = _applied(t, q, qd)
    assert np.all(np.abs(np.diff(qa, axis=0)) / DT <= robot.v_max * (1 + 1e-6))
    assert np.all(np.abs(np.diff(qda, axis=0)) / DT <= robot.a_max * (1 + 1e-6))


def test_replies_that_stay_a_cycle_late_are_repeated_once_not_frozen(rtree, robot):
    """A late reply is sent again for the next packet (the controller kept the reference before
    it); when every reply stays late the controller takes one per cycle, a cycle later, so the
    stream moves on after one repeat instead of standing still."""
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, _away(robot), 0), T0)
    for k in range(1, 40):
        r = ctl.on_feedback(Feedback(4 * k, ctl.sup.q, k), T0 + 0.004 * k)
    q = [r.q]
    for k in range(40, 60):
        q.append(ctl.on_feedback(Feedback(4 * k, ctl.sup.q, k), T0 + 0.004 * k, late=True).q)
    moved = np.abs(np.diff(q, axis=0)).max(axis=1) > 0
    assert not moved[0] and moved[1:].all() and ctl.held == 1


def test_a_stale_packet_or_a_reordered_one_gets_the_last_setpoint(rtree, robot):
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(400, _away(robot)), T0)
    r = ctl.on_feedback(Feedback(404, ctl.sup.q), T0 + 0.004)
    stale = ctl.on_feedback(Feedback(396, ctl.sup.q), T0 + 0.0045)
    assert stale.q is r.q and stale.tick.repeat and ctl.sup.ticks == 1


def test_after_a_silence_in_motion_the_stream_restarts_at_the_measured_state(rtree, robot):
    events = []
    ctl = _control(rtree, robot, events)
    ctl.on_feedback(Feedback(0, _away(robot)), T0)
    for k in range(1, 60):
        ctl.on_feedback(Feedback(4 * k, ctl.sup.q), T0 + 0.004 * k)
    assert np.abs(ctl.sup.qd).max() > 0.3  # moving
    q_meas = ctl.sup.q + 0.03  # the arm went on a little during 0.5 s of silence
    tm = 4 * 59 + 500
    assert (
        ctl.on_feedback(Feedback(tm, q_meas), T0 + tm / 1000) is None
    )  # one packet: no velocity yet
    assert (
        ctl.on_feedback(Feedback(tm, q_meas), T0 + tm / 1000 + 3e-4) is None
    )  # the same one again
    assert ctl.on_feedback(Feedback(tm + 4, q_meas), T0 + (tm + 4) / 1000) is None  # two: not yet
    assert ctl.deferred == 3 and ctl.resyncs == 0 and events == []
    tm += 8
    r = ctl.on_feedback(Feedback(tm, q_meas), T0 + tm / 1000)  # the arm stands: measured at rest
    assert ctl.resyncs == 1 and events == ["resync"]
    np.testing.assert_allclose(r.q, q_meas, atol=1e-12)  # within 1 mrad: exactly
    assert not r.qd.any()
    assert ctl.ex.mode == RETURNING  # the plan goes on (home) from the measured state
    t, q, qd = [tm / 1000], [r.q], [r.qd]
    for k in range(1, 100):  # and it goes on smoothly
        r = ctl.on_feedback(Feedback(tm + 4 * k, ctl.sup.q), T0 + (tm + 4 * k) / 1000)
        t.append((tm + 4 * k) / 1000), q.append(r.q), qd.append(r.qd)
    _assert_admissible_over_the_controller_clock(t, q, qd, robot)
    assert ctl.sup.intervened == 0


@pytest.mark.parametrize("decel", [0.0, 2.0])
def test_after_a_silence_in_motion_the_restart_takes_the_velocity_the_next_packets_measure(
    rtree, robot, decel
):
    """The arm still moves when the stream comes back (the controller slows it down, here at
    ``decel`` times a_max): the first two packets are left unanswered, and the restart at the
    third commands its measured position and the velocity at that moment, not a standstill
    nor the average over the last cycle."""
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, _away(robot)), T0)
    for k in range(1, 40):
        ctl.on_feedback(Feedback(4 * k, ctl.sup.q), T0 + 0.004 * k)
    assert not ctl.at_rest()
    v0 = np.array([0.3, -0.2, 0.1, 0.4, 0.0, -0.1])
    a = -decel * robot.a_max * np.sign(v0)
    q1 = ctl.sup.q + 0.01
    tm = 4 * 39 + 60  # 60 ms of silence

    def q_at(k):  # the arm k cycles after the first packet
        return q1 + v0 * k * DT + 0.5 * a * (k * DT) ** 2

    assert ctl.on_feedback(Feedback(tm, q_at(0)), T0 + tm / 1000) is None
    assert ctl.on_feedback(Feedback(tm + 4, q_at(1)), T0 + (tm + 4) / 1000) is None
    r = ctl.on_feedback(Feedback(tm + 8, q_at(2)), T0 + (tm + 8) / 1000)
    np.testing.assert_allclose(r.q, q_at(2), atol=1e-12)
    np.testing.assert_allclose(r.qd, v0 + a * 2 * DT, atol=1e-9)
    assert ctl.resyncs == 1 and ctl.deferred == 2


@pytest.mark.parametrize("reason", ["planner_lost", "planner_stale", "signal"])
def test_a_brake_whose_cause_is_outside_the_stream_outlasts_a_silence_and_standby(
    rtree, robot, reason
):
    """Braking for a lost or stalled planner (or a stop signal) when the controller falls
    silent: the stream restarts at the measured state, as after any silence, and the arm
    stops from there, jerk-limited: the brake stays latched (it used to be dropped, and the
    plan resumed without a planner). A controller in standby keeps it too."""
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, _away(robot)), T0)
    for k in range(1, 40):
        ctl.on_feedback(Feedback(4 * k, ctl.sup.q), T0 + 0.004 * k)
    assert np.abs(ctl.sup.qd).max() > 0.3  # moving home
    ctl.brake(reason)
    for k in range(40, 45):
        ctl.on_feedback(Feedback(4 * k, ctl.sup.q), T0 + 0.004 * k)
    v0 = ctl.sup.qd.copy()
    assert ctl.sup.braking and np.abs(v0).max() > 0.2  # braking, still moving
    q1, tm = ctl.sup.q + v0 * 0.06, 4 * 44 + 60  # 60 ms of silence: the arm went on

    def q_at(k):
        return q1 + v0 * k * DT

    assert ctl.on_feedback(Feedback(tm, q_at(0)), T0 + tm / 1000) is None
    assert ctl.on_feedback(Feedback(tm + 4, q_at(1)), T0 + (tm + 4) / 1000) is None
    r = ctl.on_feedback(Feedback(tm + 8, q_at(2)), T0 + (tm + 8) / 1000)
    np.testing.assert_allclose(r.q, q_at(2), atol=1e-12)  # the rule after a silence
    np.testing.assert_allclose(r.qd, v0, atol=1e-9)
    assert ctl.resyncs == 1 and ctl.sup.brake_reason == reason
    t, qd = [tm + 8], [r.qd]
    for k in range(3, 200):  # an arm that follows: the stop, from the measured state
        r = ctl.on_feedback(Feedback(tm + 4 * k, ctl.sup.q), T0 + (tm + 4 * k) / 1000)
        t.append(tm + 4 * k), qd.append(r.qd)
    qd = np.array(qd)
    assert np.all(np.abs(np.diff(qd, axis=0)) <= robot.a_max * DT * (1 + 1e-9))
    assert np.all(np.abs(qd[1:]) <= np.abs(qd[:-1]) + 1e-12)  # a stop, never a speed-up
    assert not qd[-50:].any() and ctl.sup.brake_reason == reason
    tm += 4 * 200 + 60  # silent again, the stop done: held where the arm settles, at rest
    q2 = ctl.sup.q + 1e-4
    for k in range(3):
        r = ctl.on_feedback(Feedback(tm + 4 * k, q2 + 1e-5 * k), T0 + (tm + 4 * k) / 1000)
    np.testing.assert_allclose(r.q, q2 + 2e-5, atol=1e-12)
    assert not r.qd.any() and ctl.resyncs == 2 and ctl.sup.brake_reason == reason
    tm += 4 * 3
    ctl.on_feedback(
        Feedback(tm, ctl.sup.q, ready=False), T0 + tm / 1000
    )  # standby, then ready again
    r = ctl.on_feedback(Feedback(tm + 4, ctl.sup.q), T0 + (tm + 4) / 1000)
    assert ctl.sup.brake_reason == reason and not r.qd.any()
    assert ctl.sup.counts[f"brake_{reason}"] == 1  # the same brake, kept: counted once


def test_a_restart_waits_for_a_velocity_at_most_a_few_packets(rtree, robot):
    """Packets that keep arriving too far apart to measure a velocity: the stream restarts
    anyway (from the measured position at rest) after DEFER_MAX unanswered packets."""
    from thinkfast.control.core import DEFER_MAX

    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, _away(robot)), T0)
    for k in range(1, 40):
        ctl.on_feedback(Feedback(4 * k, ctl.sup.q), T0 + 0.004 * k)
    q1, tm = ctl.sup.q.copy(), 4 * 39 + 60  # 60 ms of silence, then packets 4 cycles apart:
    replies = []  # no silence each, but too far apart to measure a velocity
    for k in range(DEFER_MAX + 1):
        replies.append(ctl.on_feedback(Feedback(tm + 16 * k, q1), T0 + (tm + 16 * k) / 1000))
    assert replies[:DEFER_MAX] == [None] * DEFER_MAX and replies[-1] is not None
    assert not replies[-1].qd.any()
    np.testing.assert_allclose(replies[-1].q, q1, atol=1e-12)


def test_packets_each_after_a_silence_are_answered_after_a_few(rtree, robot):
    """A starved controller whose every packet comes after a silence (250 ms apart): each
    silence does not start the wait for a velocity again, so the stream restarts after at
    most DEFER_MAX unanswered packets instead of never (the controller's communication
    timeout would end the session)."""
    from thinkfast.control.core import DEFER_MAX

    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, _away(robot)), T0)
    for k in range(1, 40):
        ctl.on_feedback(Feedback(4 * k, ctl.sup.q), T0 + 0.004 * k)
    assert not ctl.at_rest()
    q1, tm = ctl.sup.q.copy(), 4 * 39
    replies = []
    for k in range(1, 3 * (DEFER_MAX + 1) + 1):
        replies.append(ctl.on_feedback(Feedback(tm + 250 * k, q1), T0 + (tm + 250 * k) / 1000))
    assert replies[:DEFER_MAX] == [None] * DEFER_MAX and replies[DEFER_MAX] is not None
    np.testing.assert_allclose(replies[DEFER_MAX].q, q1, atol=1e-12)
    answered = sum(r is not None for r in replies)  # each restart in motion measures again
    assert answered >= 3 and ctl.deferred <= 3 * DEFER_MAX


def test_a_superseded_packet_measures_the_velocity_a_restart_starts_with(rtree, robot):
    """After this host stalled (the controller went on sending), the restart takes the measured
    velocity from the peer's packet just before the answered one."""
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, robot.home), T0)
    v = np.array([0.4, -0.2, 0.1, 0.5, 0.0, -0.3])
    q_meas = robot.home + v * 0.1
    r = ctl.on_feedback(Feedback(100, q_meas), T0 + 0.1, before=(96, q_meas - v * 0.004))
    assert r.tick.resync
    np.testing.assert_allclose(r.q, q_meas, atol=1e-12)
    np.testing.assert_allclose(r.qd, v, rtol=1e-9)


def test_the_measured_velocity_seeds_a_restart_when_two_packets_measure_it(rtree, robot):
    ctl = _control(rtree, robot)
    ctl.on_feedback(Feedback(0, robot.home), T0)
    v = np.array([0.2, -0.1, 0.0, 0.3, 0.0, 0.0])
    ctl.rate.fb = (ctl.clock.t, robot.home)  # the last packet before the silence
    tm = 100  # 100 ms later: a silence
    r = ctl.on_feedback(Feedback(tm, robot.home + v * 0.004), T0 + 0.1)
    assert r.tick.resync and not r.qd.any()  # 100 ms apart: no velocity measured
    r2 = ctl.on_feedback(Feedback(tm + 4, robot.home + v * 0.008), T0 + 0.104)
    assert not r2.tick.resync  # consecutive: the velocity is measured from now on
    assert ctl.rate.measure(ctl.clock.tick(tm + 8, T0 + 0.108), robot.home + v * 0.012) is not None


def _lagging_run(ctl, robot, lag_cycles, freeze=(math.inf, math.inf), n=400):
    """Feedback that follows the command ``lag_cycles`` late (a slow servo), frozen during the
    cycles ``freeze`` = [from, to) (an arm that stops following). Returns the replies."""
    ctl.on_feedback(Feedback(0, _away(robot)), T0)
    sent = [ctl.sup.q]
    out = []
    for k in range(1, n):
        q_meas = sent[max(0, len(sent) - 1 - lag_cycles)]
        if freeze[0] <= k < freeze[1]:
            q_meas = sent[freeze[0] - 1 - lag_cycles]
        r = ctl.on_feedback(Feedback(4 * k, q_meas), T0 + 0.004 * k)
        sent.append(r.q)
        out.append(r)
    return out


def test_a_servo_lagging_within_the_tracking_lag_is_followed_without_fault(rtree, robot):
    ctl = _control(rtree, robot)
    _lagging_run(ctl, robot, lag_cycles=int(0.15 / DT))
    assert not ctl.sup.braking and ctl.fault_count == 0 and ctl.sup.intervened == 0


def test_an_arm_that_stops_following_brakes_then_recovers_home_by_itself(rtree, robot):
    events = []
    ctl = _control(rtree, robot, events)
    replies = _lagging_run(ctl, robot, lag_cycles=5, freeze=(40, 120), n=700)
    assert ctl.sup.counts["brake_deviation"] == 1
    assert any(r.mode == "brake" for r in replies)
    # the arm stands (frozen); once the commanded stop is done and it has stood for
    # recover_after, the stream restarts from it and the executor returns home
    assert events == ["brake", "recover"] and ctl.fault_count == 1 and not ctl.latched
    assert ctl.ex.mode == IDLE and not ctl.sup.braking  # home again, ready for a throw
    np.testing.assert_allclose(ctl.sup.q, robot.home, atol=1e-6)


def test_repeated_faults_within_the_window_latch_fault(rtree, robot):
    events = []
    ctl = _control(rtree, robot, events)
    q_frozen = _away(robot)
    ctl.on_feedback(Feedback(0, q_frozen), T0)
    tm = 0
    for _ in range(3000):  # the arm never moves: every return home trips the check again
        tm += 4
        ctl.on_feedback(Feedback(tm, q_frozen), T0 + tm / 1000)
        if ctl.latched:
            break
    assert ctl.latched and ctl.mode() == FAULT and ctl.ex.mode == FAULT
    assert events == ["brake", "recover", "brake", "recover", "brake", "fault_latched"]
    for _ in range(50):  # latched: holds the measured position, moves nothing
        tm += 4
        r = ctl.on_feedback(Feedback(tm, q_frozen), T0 + tm / 1000)
        assert not r.qd.any()
    np.testing.assert_allclose(r.q, np.clip(q_frozen, ctl.sup.limits.q_min, ctl.sup.limits.q_max))


def test_clock_stamps_wrap_around_uint32_without_a_restart():
    clock = ControllerClock(DT, 0.02)
    assert clock.tick(2**32 - 4, T0).resync
    tick = clock.tick(0, T0 + 0.004)
    assert not tick.resync and tick.elapsed == pytest.approx(0.004)


def test_clock_without_stamps_snaps_arrivals_to_the_cycle_grid():
    clock = ControllerClock(DT, 0.02)
    clock.tick(None, T0)
    jitter = [0.0011, -0.0013, 0.0016, 0.0, -0.0009]
    t = T0
    for k, j in enumerate(jitter, 1):
        tick = clock.tick(None, T0 + 0.004 * k + j)
        assert tick.elapsed == pytest.approx(0.004, rel=1.01e-4) and not tick.repeat
        t += tick.elapsed
    assert clock.tick(None, T0 + 0.004 * 5 + 0.0004).repeat  # a duplicate right behind
    assert clock.tick(None, T0 + 0.004 * 6 + 0.0002).elapsed == pytest.approx(0.004, rel=2e-4)
    assert clock.tick(None, T0 + 0.5).resync


def test_a_controller_clock_restart_is_a_resync_not_a_stale_packet():
    clock = ControllerClock(DT, 0.02)
    clock.tick(500_000, T0)
    clock.tick(500_004, T0 + 0.004)
    assert clock.tick(12, T0 + 0.008).resync  # tm restarted with a new EGM session
    assert math.isclose(clock.t, T0 + 0.008)


def test_clock_counts_the_cycles_by_seqno_whatever_tm_does():
    """``tm`` of a clock that is not hard real-time (steps of 3-5 ms, a repeat, a 30 ms jump):
    every new seqno is one cycle of 4 ms, a repeated seqno is a duplicate."""
    clock = ControllerClock(DT, 0.02)
    clock.tick(1000, T0, seqno=10)
    for k, tm in enumerate([1003, 1008, 1008, 1041, 1044], 1):  # 3, 5, 0, 33, 3 ms
        tick = clock.tick(tm, T0 + 0.004 * k, seqno=10 + k)
        assert tick.elapsed == DT and not tick.repeat and not tick.resync
    assert clock.tick(1044, T0 + 0.0201, seqno=15).repeat  # the same packet again
    assert clock.tick(1041, T0 + 0.0202, seqno=14).repeat  # a stale one
    assert math.isclose(clock.t, T0 + 5 * DT)
    tick = clock.tick(1052, T0 + 0.028, seqno=17)  # one packet lost on the way
    assert tick.elapsed == pytest.approx(2 * DT) and not tick.resync
    assert clock.tick(1100, T0 + 0.05, seqno=23).resync  # 6 cycles unanswered: a silence


def test_clock_falls_back_to_tm_when_seqno_does_not_count():
    """A controller that leaves seqno at 0, or restarts it, is placed by ``tm``."""
    clock = ControllerClock(DT, 0.02)
    clock.tick(1000, T0, seqno=0)
    tick = clock.tick(1008, T0 + 0.008, seqno=0)
    assert tick.elapsed == pytest.approx(0.008) and not tick.repeat
    assert clock.tick(1008, T0 + 0.0082, seqno=0).repeat
    clock.tick(1012, T0 + 0.012, seqno=500)
    tick = clock.tick(1016, T0 + 0.016, seqno=1)  # seqno restarted, tm goes on
    assert tick.elapsed == pytest.approx(0.004) and not tick.resync and not tick.repeat
    assert clock.tick(1020, T0 + 0.020, seqno=2).elapsed == DT
    clock.tick(1024, T0 + 0.024, seqno=0)  # restarted soon after: not a stale packet
    assert clock.tick(1028, T0 + 0.028, seqno=1).elapsed == DT


@pytest.mark.parametrize("planner", ["tree", "naive"])
def test_ordinary_throws_never_need_the_supervisor_and_stay_jerk_limited(rtree, robot, planner):
    """Throws through the control core with the simulated servo's feedback: every request is
    admissible as planned (0 interventions), and the commanded motion over the controller's clock
    is jerk-limited (third differences of positions / dt^3 <= j_max)."""
    from thinkfast.control.intake import Intake
    from thinkfast.sim.camera import CameraModelConfig, detection_payload, observe
    from thinkfast.sim.controller import ServoConfig, SimController
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    ex = Executor(rtree, robot, CFG, planner)
    sup = SafetySupervisor(robot_limits(robot, CFG.safety.position_margin), CFG.safety, robot.home)
    ctl = ControlCore(ex, sup, CFG.safety)
    arm = SimController(ServoConfig(), q0=robot.home)
    intake = Intake(CFG.camera, CFG.detections)
    t, tm, q = 0.0, 0, []
    for i, th in enumerate(sample_throws(ThrowConfig(), 3, 3)):
        t_rel = t + 0.5 + th.t_release
        dets = observe(th, CameraModelConfig(), CFG.camera, np.random.default_rng(i), t_rel)
        k, t_end = 0, t_rel + th.flight_time + 3.5
        while t < t_end:
            while k < len(dets) and dets[k].delivery_time <= t:
                acc = intake.take(detection_payload(dets[k]), None)
                if acc is not None:
                    ex.on_detection(ctl.t_next if ctl.last else t, acc.stamp, acc.position)
                k += 1
            r = ctl.on_feedback(Feedback(tm, arm.q), t)
            arm.command(r.q, r.qd, arm.t)
            arm.step(DT)
            q.append(r.q)
            t, tm = t + DT, tm + 4
    assert ex.episodes == 3 and ctl.fault_count == 0
    assert sup.ticks > 1000 and sup.intervened == 0, sup.counts
    jerk = np.abs(np.diff(np.array(q), 3, axis=0)) / DT**3
    assert np.all(jerk <= robot.j_max * (1 + 1e-6))


def _throws_with_missed_replies(rtree, robot, planner, miss=0.01, n=5, seed=11, late=0.0):
    """Throws through the core with the simulated servo; each reply misses its cycle with
    probability ``miss`` (this host was late: the core never sees that packet, the controller
    keeps the last reference) or, with probability ``late``, arrives after the controller's next
    cycle began (it keeps the last reference for that cycle and applies the next reply; the core
    hears of it with the next packet). Returns the references the controller applied, one per
    cycle (q, speedRef), the count of misses in motion and the core."""
    from thinkfast.control.intake import Intake
    from thinkfast.sim.camera import CameraModelConfig, detection_payload, observe
    from thinkfast.sim.controller import ServoConfig, SimController
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    ex = Executor(rtree, robot, CFG, planner)
    sup = SafetySupervisor(robot_limits(robot, CFG.safety.position_margin), CFG.safety, robot.home)
    ctl = ControlCore(ex, sup, CFG.safety)
    arm = SimController(ServoConfig(), q0=robot.home)
    intake, rng = Intake(CFG.camera, CFG.detections), np.random.default_rng(seed)
    t, last, q, qd, moving_misses, was_late = 0.0, None, [], [], 0, False
    for i, th in enumerate(sample_throws(ThrowConfig(), n, seed)):
        t_rel = t + 0.5 + th.t_release
        dets = observe(th, CameraModelConfig(), CFG.camera, np.random.default_rng(i), t_rel)
        k, t_end = 0, t_rel + th.flight_time + 2.0
        while t < t_end:
            while k < len(dets) and dets[k].delivery_time <= t:
                ctl.intake = intake
                ctl.on_detection(detection_payload(dets[k]), None, ctl.t_next)
                k += 1
            seqno, tm = arm.header()
            if last is not None and rng.random() < miss:
                moving_misses += bool(np.abs(last.qd).max() > 0.1)
            else:
                r = ctl.on_feedback(Feedback(tm, arm.q, seqno), t, late=was_late)
                was_late = last is not None and rng.random() < late
                if was_late:
                    moving_misses += bool(np.abs(last.qd).max() > 0.1)
                else:
                    last = r
                    arm.command(last.q, last.qd, arm.t)
            q.append(last.q), qd.append(last.qd)
            arm.step(DT)
            t += DT
    return np.array(q), np.array(qd), moving_misses, ctl


@pytest.mark.parametrize("planner,late", [("tree", 0.0), ("naive", 0.0), ("naive", 0.01)])
def test_missed_replies_the_reference_the_controller_applies_stays_within_the_limits(
    rtree, robot, planner, late
):
    """1 % of the replies miss their cycle (and 1 % arrive a cycle late), in motion too. Over
    the controller's clock, holds counted: the applied positions move within ``v_max`` and
    ``speedRef`` changes within ``a_max`` (before: the reply after a hold was two cycles of
    motion ahead, up to 2x each). A hold itself stops the position reference for a cycle: no
    later reply can undo that."""
    q, qd, moving_misses, ctl = _throws_with_missed_replies(rtree, robot, planner, late=late)
    assert moving_misses >= 3 and ctl.held >= moving_misses and ctl.fault_count == 0
    assert ctl.sup.intervened == 0, ctl.sup.counts
    v_ratio = (np.abs(np.diff(q, axis=0)) / DT / robot.v_max).max()
    a_ratio = (np.abs(np.diff(qd, axis=0)) / DT / robot.a_max).max()
    assert v_ratio <= 1.01 and a_ratio <= 1.05, (v_ratio, a_ratio)
