"""The reply loop in a process of its own (``thinkfast-run --reply-process``): a planner that
stalls costs no reply, one that stalls too long brakes the arm smoothly and resumes, one that is
killed leaves the arm braked and still answered. Real processes, real UDP with protobuf EGM
against the simulated controller, real zenoh on loopback."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
from daemon_harness import DaemonRun, ballistic_throw, publish_throw

from thinkfast.control.config import RunConfig
from thinkfast.sim.realtime import daemon_log

DT = 0.004
REPLY = ("--reply-process",)
RESYNC_CYCLES = round(RunConfig().safety.resync_after / DT)  # cycles unanswered: no restart yet


@pytest.fixture(scope="module")
def tree_file(small_tree_015):
    return small_tree_015


def _limits(q, qd, cycles, robot, margin: float = 0.005) -> None:
    """Positions and velocities within the limits; velocity steps within a_max over the
    controller cycles between two commands (a reply may answer a later cycle)."""
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(qd))
    assert np.all(q >= robot.q_lower + margin - 1e-9) and np.all(q <= robot.q_upper - margin + 1e-9)
    assert np.all(np.abs(qd) <= robot.v_max + 1e-9)
    assert np.all(cycles >= 0)
    assert np.all(np.abs(np.diff(qd, axis=0)) <= robot.a_max * DT * cycles[:, None] + 1e-9)


def _restarts(t, q, hist) -> np.ndarray:
    """Per pair of commands received at ``t`` (n - 1,): the second is a restart after a silence
    (more than ``resync_after`` of cycles between them, and it commands a position the arm
    reported in one of them: the rule after a silence)."""
    out = np.zeros(len(t) - 1, dtype=bool)
    for k in np.flatnonzero(np.round(np.diff(t) / DT) > RESYNC_CYCLES):
        sent = (hist.t > t[k] + 1e-9) & (hist.t <= t[k + 1] + 1e-9)  # the packets between
        out[k] = sent.any() and np.abs(hist.q[sent] - q[k + 1]).max(axis=1).min() < 1e-9
    return out


def _held(cmds, n: int) -> bool:
    """More than ``n`` commands received, the last 20 of them at rest."""
    return len(cmds.t) > n and not cmds.qd[-20:].any()


def _says_held(status: dict) -> bool:
    """A status of the reply process on its own, its arm held at rest."""
    return status.get("fault") == "planner_lost" and not any(status["qd"])


def _runs(linked: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) of the runs of commands ``[start, end)`` whose neighbours are ``linked``
    (n - 1,), each of at least two commands."""
    cuts = np.r_[0, np.flatnonzero(~linked) + 1, len(linked) + 1]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b - a > 1]


def _throw(run: DaemonRun) -> None:
    t_release = time.time() + 0.8
    _, _, at = ballistic_throw((0.25, 1.25), 0.8, t_release, (7.8, -0.2, 1.5))
    publish_throw(run, at, t_release, 0.8)


def _gone(pid: int, timeout: float) -> bool:
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(") ")[1][0] == "Z":
                    return True  # ended (its new parent reaps it)
        except FileNotFoundError:
            return True
        time.sleep(0.05)
    return False


def _stalled_throw(tree_file, tmp_path, robot, stall: str, seconds: float):
    """A throw at a daemon whose planner stalls (``SECONDS@AFTER`` the throw executes), until
    it is idle again: (run, its log, its recorded EGM rows)."""
    extra = REPLY + ("--test-stall-planner", stall)
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "tree", q0=robot.home, extra=extra)
    try:
        _throw(run)  # a stalled planner publishes no status: the last one is not idle
        assert run.wait_state("idle", timeout=10.0 + seconds), run.status[-1]
    finally:
        code, err = run.stop()
    assert code == 0, err
    return run, err, run.egm_rows()


@pytest.mark.realtime
def test_a_planner_stall_of_50_ms_costs_no_reply_and_the_arm_follows_its_plan(
    tree_file, tmp_path, robot
):
    run, err, rows = _stalled_throw(tree_file, tmp_path, robot, "0.05@0.1", 0.0)
    assert "stalling the planner for 0.050 s" in err
    assert "planner_stale" not in err
    braking = rows[:, 20] == 1.0
    k = int(np.argmax(braking)) if braking.any() else len(rows)
    assert np.all(braking[k:])  # never braked but at the end (the test's SIGINT, at rest)
    assert np.abs(rows[: k - 1, 14:20]).max() > 0.3  # the throw was executed through the stall
    last = run.status[-1]
    assert last["reply_process"]["planner_stale"] == 0 and last["throws"] == 1
    egm = last["egm"]
    assert egm["reply_errors"] == 0 and egm["deferred"] == 0
    _limits(rows[:, 8:14], rows[:, 14:20], np.diff(rows[:, 1]), robot)
    assert np.allclose(rows[-1, 8:14], robot.home, atol=2e-3)


@pytest.mark.realtime
def test_a_planner_stall_of_2_s_brakes_smoothly_and_the_throw_resumes_after_it(
    tree_file, tmp_path, robot
):
    run, err, rows = _stalled_throw(tree_file, tmp_path, robot, "2@0.15", 2.0)
    assert "planner_stale" in err and "planner_resumed" in err
    _limits(rows[:, 8:14], rows[:, 14:20], np.diff(rows[:, 1]), robot)
    braking = rows[:, 20] == 1.0
    first = int(np.argmax(braking))
    end = first + int(np.argmin(braking[first:]))  # the first reply after the brake
    assert braking.any() and end > first  # (the last rows brake on the test's SIGINT)
    assert np.abs(rows[end:, 14:20]).max() > 0.05  # it moved on after the stall: home
    assert np.abs(rows[first - 1, 14:20]).max() > 0.05  # it was moving when the brake came
    assert np.all(rows[end - 1, 14:20] == 0.0)  # stopped before resuming
    speed = np.abs(rows[first:end, 14:20])
    overshoot = robot.a_max**2 / (2 * robot.j_max) + robot.a_max * DT
    assert np.all(speed.max(axis=0) <= speed[0] + overshoot)  # a stop, never a speed-up
    # 2 s of stall: the stop lasted most of it (the loop answered throughout, holding)
    assert rows[end, 0] - rows[first, 0] > 1.0
    assert run.status[-1]["reply_process"]["planner_stale"] == 1
    assert np.allclose(rows[-1, 8:14], robot.home, atol=2e-3)  # the throw ended, back home


@pytest.mark.realtime
def test_a_killed_planner_leaves_the_arm_braked_and_still_answered(tree_file, tmp_path, robot):
    """SIGKILL of the planner process while the arm moves (home, from where the daemon found
    it: a motion no load can cancel, as a throw's can be): the reply process goes on
    answering, brakes to a stop and holds it, and says so on zenoh.

    The replies are judged as the reply process made them, one supervisor step each, in the
    order they came: the simulated controller runs on this loaded test host without a real-time
    clock, so it reads some replies a cycle after they arrived and applies two in one cycle (a
    controller's own stall, which the fault campaign's real-time controller does not have). A
    stall of the reply process longer than ``resync_after`` restarts the stream at a position
    the arm reported (the rule after a silence, tests/test_egm_control.py): no difference is
    taken across it, and the brake outlasts it."""
    away = robot.home + np.array([0.9, -0.3, 0.3, 0.5, 0.3, -0.4])  # it returns home at once
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "tree", q0=away, extra=REPLY)
    child = None
    try:
        deadline = time.time() + 20.0
        while time.time() < deadline and np.abs(run.sim.qd).max() < 0.3:
            time.sleep(0.005)
        assert np.abs(run.sim.qd).max() >= 0.3  # the arm moves (home)
        child = run.status[-1]["reply_process"]["pid"]
        n_before = len(run.sim.commands().t)
        run.proc.kill()  # SIGKILL the planner process
        run.proc.wait(5.0)
        deadline = time.time() + 15.0  # (a loaded host slows the simulated controller down)
        cmds = run.sim.commands()
        while time.time() < deadline and not _held(cmds, n_before + 60):
            time.sleep(0.2)
            cmds = run.sim.commands()
        assert len(cmds.t) - n_before > 60  # the controller is still answered
        q, qd, t = cmds.q[n_before - 5 :], cmds.qd[n_before - 5 :], cmds.t[n_before - 5 :]
        assert np.abs(qd[0]).max() > 0.05  # commanded in motion at the kill
        assert np.all(qd[-20:] == 0.0)  # braked to a stop, holding
        restart = _restarts(t, q, run.sim.history())
        step = np.abs(np.diff(qd, axis=0)) / (robot.a_max * DT)
        worst = int(np.argmax(np.where(restart[:, None], 0.0, step).max(axis=1)))
        at = slice(max(0, worst - 3), worst + 5)  # what a failure shows
        context = (worst, np.round(np.diff(t[at]) / DT), np.round(qd[at], 4), restart[at])
        for k0, k1 in _runs(~restart):  # one supervisor step per reply, but at a restart
            try:
                _limits(q[k0:k1], qd[k0:k1], np.ones(k1 - k0 - 1), robot)
            except AssertionError as exc:
                raise AssertionError(f"the worst step and around it: {context}") from exc
        # zenoh reconnects to the same endpoint after a backoff; the reply process's session
        # tries again every second until the dead planner's endpoint is its own
        deadline = time.time() + 60.0  # (once a second: the first may predate the stop)
        while time.time() < deadline and not _says_held(run.status[-1]):
            time.sleep(0.1)
        last = run.status[-1]  # not silence: the reply process's own status
        assert last["state"] == "fault" and last["fault"] == "planner_lost", (
            last, daemon_log(run.proc)[-2000:])  # fmt: skip
        # (a planner that stalled past planner_timeout just before the kill braked first:
        # the first reason is kept)
        assert last["brake_reason"] in ("planner_lost", "planner_stale"), last
        assert last["braking"] and not any(last["qd"])
        os.kill(child, signal.SIGTERM)  # it ends when told
        assert _gone(child, 10.0)
        child = None
    finally:
        if child is not None:
            os.kill(child, signal.SIGKILL)
        _, err = run.stop()
    assert "planner process" in err and "lost: braking to a stop and holding" in err


def test_the_deadline_brakes_on_a_silent_planner_and_resumes_from_the_stop(robot):
    """ReplyLoop driven packet by packet (no wall clock): a heartbeat older than
    planner_timeout brakes along the supervisor's stop; once stopped and the planner speaks,
    the loop plans on from the commanded state (a resync the planner is told of) and moves."""
    from thinkfast.contract.egm import RobotFeedback
    from thinkfast.control.config import RunConfig
    from thinkfast.control.plan import SIZE, plan_vector
    from thinkfast.control.segments import STEER, move
    from thinkfast.link.egm import egm_feedback, open_egm
    from thinkfast.link.registry import LinkSpec
    from thinkfast.reply.process import ReplyLoop
    from thinkfast.reply.rows import CALL, COL, EVENT, EVENTS, REPLY, WIDTH
    from thinkfast.reply.shared_plan import RowRing, Seqlock

    cfg = RunConfig()
    block, ring = Seqlock(SIZE), RowRing(WIDTH)
    loop = ReplyLoop(robot, cfg, block, ring, os.getppid())
    loop.link = open_egm(LinkSpec("127.0.0.1:0"), loop.reply)  # its counters in the rows
    try:
        core, sup, f = loop.core, loop.core.sup, loop.follower
        qs = []

        def packet(seqno: int) -> None:
            q = robot.home if not qs else qs[-1]  # an arm that follows exactly
            q, _ = loop.reply(egm_feedback(RobotFeedback(seqno, 4 * seqno, q, True, True, True)))
            qs.append(np.array(q))
            loop.after(True)

        packet(1)  # the stream starts: the follower holds home (epoch 1)
        t0 = core.clock.t + DT
        target = robot.home[:3] + np.array([0.8, -0.3, 0.3])
        seg = move(f.timeline.steer, STEER, np.r_[robot.home[:3], np.zeros(6)], target, t0, 2)
        block.write(plan_vector(1, f.epoch, "executing", [seg], f.normal, None))
        block.beat(10.0)
        loop.watch_plan(10.001)
        assert f.plan_id == 1
        for k in range(2, 60):
            packet(k)
            loop.watch_plan(10.0 + cfg.safety.planner_timeout * k / 100)  # in time
        assert not sup.braking and np.abs(sup.qd).max() > 0.5  # moving along the plan
        loop.watch_plan(10.0 + cfg.safety.planner_timeout + 0.01)  # no word: too late
        assert sup.brake_reason == "planner_stale"
        k = 60
        while not sup.stopped:
            packet(k)
            k += 1
            assert k < 400
        block.beat(11.0)
        loop.watch_plan(11.001)  # the planner speaks again
        assert not sup.braking
        for j in range(k, k + 40):
            packet(j)
        assert np.abs(sup.qd).max() > 0.1  # on its way to the target again
        rows = ring.take()
        events = [EVENTS[int(r[COL["code"]])] for r in rows if r[COL["type"]] == EVENT]
        assert events == ["planner_stale", "planner_resumed"]
        calls = rows[rows[:, COL["type"]] == CALL]
        assert len(calls) == 2 and f.epoch == 2  # the start, and the resync after the stop
        replies = rows[rows[:, COL["type"]] == REPLY]
        qd = replies[:, COL["qd"]]
        assert np.all(np.abs(np.diff(qd, axis=0)) <= robot.a_max * DT + 1e-9)
        assert np.all(np.abs(qd) <= robot.v_max + 1e-9)
    finally:
        loop.link.close()
        block.close()
        ring.close()


@pytest.mark.realtime
def test_a_dead_reply_process_stops_the_daemon_with_exit_1_and_says_why(tree_file, tmp_path, robot):
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "tree", q0=robot.home, extra=REPLY)
    try:
        child = run.status[-1]["reply_process"]["pid"]
        os.kill(child, signal.SIGKILL)
        code = run.proc.wait(20.0)
    finally:
        _, err = run.stop()
    assert code == 1
    assert f"the EGM reply process {child} died (exit code -9)" in err


def _replies_with_plans_landing(robot, monkeypatch, prepare: bool) -> tuple[np.ndarray, int]:
    """ReplyLoop packet by packet on a simulated clock, an arm that follows exactly, and a new
    plan (another target, another shield normal) every few packets, landing after the next
    reply was prepared (``prepare``) or with nothing prepared: (the replies (n, 12), how many
    were the prepared ones)."""
    from types import SimpleNamespace

    from thinkfast.contract.egm import RobotFeedback
    from thinkfast.control.config import RunConfig
    from thinkfast.control.plan import SIZE, plan_vector
    from thinkfast.control.segments import STEER, move
    from thinkfast.link.egm import egm_feedback, open_egm
    from thinkfast.link.registry import LinkSpec
    from thinkfast.reply import process as reply_process
    from thinkfast.reply.process import ReplyLoop
    from thinkfast.reply.rows import WIDTH
    from thinkfast.reply.shared_plan import RowRing, Seqlock

    now = [100.0]
    clock = SimpleNamespace(time=lambda: now[0], monotonic=lambda: now[0])
    monkeypatch.setattr(reply_process, "time", clock)
    cfg = RunConfig()
    block, ring = Seqlock(SIZE), RowRing(WIDTH)
    loop = ReplyLoop(robot, cfg, block, ring, os.getppid())
    loop.link = open_egm(LinkSpec("127.0.0.1:0"), loop.reply)
    rng = np.random.default_rng(4)
    out, used, q, plan_id, seg = [], 0, robot.home, 0, None
    try:
        core, f = loop.core, loop.follower
        for k in range(1, 160):
            now[0] = 100.0 + k * DT
            ahead = core._prepared.ahead if core._prepared is not None else None
            q, qd = loop.reply(egm_feedback(RobotFeedback(k, 4 * k, q, True, True, True)))[:2]
            used += ahead is not None and q is ahead.result[0]
            out.append(np.r_[q, qd])
            loop.after(True)
            if prepare:
                core.prepare()
            if k % 6 == 1:  # the planner's next plan lands before the next packet
                plan_id, t_next = plan_id + 1, core.t_next
                target = robot.home[:3] + rng.uniform(-0.4, 0.4, 3)
                state = np.r_[robot.home[:3], np.zeros(6)] if seg is None else seg.state(t_next)
                seg = move(f.timeline.steer, STEER, state, target, core.t_next, 2)
                normal = np.r_[1.0, rng.uniform(-0.5, 0.5, 2)]
                normal /= np.linalg.norm(normal)
                block.write(plan_vector(plan_id, f.epoch, "executing", [seg], normal, None))
            block.beat(now[0])
            loop.watch_plan(now[0])
            if prepare:
                core.prepare()
        assert f.plan_id == plan_id and core.sup.intervened == 0
    finally:
        loop.link.close()
        block.close()
        ring.close()
    return np.array(out), used


def test_a_reply_prepared_ahead_is_bit_for_bit_the_one_computed_when_its_packet_comes(
    robot, monkeypatch
):
    """The loop prepares each reply as soon as it can, before the planner's next plan may land:
    a new plan voids it, the follower forgets having been asked (the wrist steps again from
    where it was, towards the new plan's normal) and the reply is prepared again. Every reply
    is the one computed without preparing anything, and nearly all are the prepared ones."""
    want, _ = _replies_with_plans_landing(robot, monkeypatch, prepare=False)
    got, used = _replies_with_plans_landing(robot, monkeypatch, prepare=True)
    assert np.abs(want[:, 9:]).max() > 0.05  # the wrist turns: the normals make a difference
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert used >= len(got) - 2  # all but the first ones (nothing to prepare from)
