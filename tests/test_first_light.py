"""First light on a real cell: shadow mode, speed scale, controller state, the move home.

The daemon runs as a real process against the simulated EGM controller over UDP and zenoh on
loopback (tests/daemon_harness.py); the way-home check runs the real executor and collision model.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time

import h5py
import numpy as np
import pytest

from tests.daemon_harness import DaemonRun, ballistic_throw, publish_throw, until
from thinkfast.sim.realtime import daemon_log

DT = 0.004


@pytest.fixture(scope="module")
def tree_file(small_tree_015):
    return small_tree_015


def _throw(run, aim=(0.25, 1.25), flight=0.8):
    t_release = time.time() + 0.6
    _, _, at = ballistic_throw(aim, flight, t_release)
    publish_throw(run, at, t_release, flight)
    return t_release + flight


@pytest.mark.realtime
def test_shadow_plans_the_throw_and_commands_the_measured_position(tree_file, tmp_path, robot):
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "tree", q0=robot.home, extra=("--shadow",))
    try:
        _throw(run)
        time.sleep(1.0)
        statuses = list(run.status)
        hist = run.sim.history()
    finally:
        code, err = run.stop()
    assert code == 0, err
    rows = run.egm_rows()
    wire = run.sim.commands()  # as the controller decoded them from the datagrams
    # every reply is the position measured when the stream started, at rest
    np.testing.assert_allclose(wire.q, np.broadcast_to(robot.home, wire.q.shape), atol=1e-6)
    assert np.all(np.abs(wire.qd) < 1e-9)
    assert np.max(np.abs(hist.q - robot.home)) < 1e-9  # the arm never moved
    assert np.max(np.abs(rows[:, 2:8] - robot.home)) < 1e-9  # measured: home throughout
    # ... while the record holds the motion the arm would have followed
    assert np.max(np.abs(rows[:, 8:14] - robot.home)) > 0.05
    assert np.max(np.abs(rows[:, 14:20])) > 0.1
    with h5py.File(run.record) as f:
        assert f.attrs["shadow"] == 1
    # ... while the status showed the motion the planner would have commanded
    shadows = [s["shadow"] for s in statuses if s.get("shadow")]
    assert shadows, "no shadow block in the status"
    moved = max(np.max(np.abs(np.array(s["q"]) - robot.home)) for s in shadows)
    assert moved > 0.05, moved
    assert any(s["mode"] == "executing" for s in shadows)
    assert all(s["mode"] == "shadow" for s in run.setpoints)


@pytest.mark.realtime
def test_speed_scale_keeps_every_reply_within_the_scaled_limits(tree_file, tmp_path, robot):
    scale = 0.2
    run = DaemonRun(
        tree_file, tmp_path / "rec.h5", "tree", q0=robot.home, extra=("--speed-scale", str(scale))
    )
    try:
        _throw(run)
        assert run.wait_state("idle", timeout=20.0)
        time.sleep(0.2)
        status = run.status[-1]
        wire = run.sim.commands()  # as the controller decoded them from the datagrams
    finally:
        code, err = run.stop()
    assert code == 0, err
    # the throw and the way home were served (how many cycles that took depends on the host)
    assert len(wire.t) > 100 and np.max(np.abs(wire.q - robot.home)) > 0.05
    assert np.all(np.abs(wire.qd) <= scale * robot.v_max + 1e-6)  # degrees on the wire: rounding
    rows = run.egm_rows()
    qd, cycles = rows[:, 14:20], np.diff(rows[:, 1])[:, None]
    assert np.max(np.abs(rows[:, 8:14] - robot.home)) > 0.05  # it did move
    assert np.all(np.abs(qd) <= scale * robot.v_max + 1e-9)
    assert np.all(np.abs(np.diff(qd, axis=0)) <= scale * robot.a_max * DT * cycles + 1e-9)
    assert status["speed_scale"] == scale and status["interventions"]["intervened"] == 0


def test_speed_scale_is_checked(tree_file, tmp_path):
    from thinkfast.daemon.cli import main

    for bad in (["--speed-scale", "0"], ["--speed-scale", "1.5"]):
        with pytest.raises(SystemExit) as exc:
            main(["--tree", str(tree_file), *bad])
        assert exc.value.code == 1
    with pytest.raises(SystemExit) as exc:
        main(["--tree", str(tree_file), "--planner", "tree-rest", "--speed-scale", "0.5"])
    assert exc.value.code == 1
    cfg = tmp_path / "run.toml"
    cfg.write_text("[choice]\nbranches = true\n")
    with pytest.raises(SystemExit) as exc:
        main(["--tree", str(tree_file), "--config", str(cfg), "--speed-scale", "0.5"])
    assert exc.value.code == 1


@pytest.mark.realtime
def test_motors_off_holds_the_measured_position_and_motion_resumes_when_on(
    tree_file, tmp_path, robot
):
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "naive", q0=robot.home)
    try:
        run.sim.motors_on = False
        time.sleep(0.3)
        _throw(run)
        time.sleep(0.8)
        off = run.status[-1]
        n_off = len(run.egm_rows())
        run.sim.motors_on = True
        time.sleep(0.3)
        on = run.status[-1]
        _throw(run, aim=(-0.25, 1.1))
        assert run.wait_state("idle", timeout=10.0)
    finally:
        code, err = run.stop()
    assert code == 0, err
    rows = run.egm_rows()
    standby = rows[50:n_off]  # after the first packets, while the motors were off
    assert np.max(np.abs(standby[:, 8:14] - standby[:, 2:8])) < 1e-9
    assert np.all(standby[:, 14:20] == 0.0)
    assert off["controller"]["motors_on"] is False and off["controller"]["standby"]
    assert off["controller"]["standby_replies"] > 100
    assert on["controller"]["ready"] and not on["controller"]["standby"]
    assert np.max(np.abs(rows[n_off:, 8:14] - robot.home)) > 0.05  # the second throw moved it
    assert "controller_state" in err and "controller_ready" in err
    ends = [json.loads(line.split(" throw_end ", 1)[1]) for line in err.splitlines()
            if " throw_end " in line]  # fmt: skip
    assert len(ends) == 2 and ends[-1]["executed"] and 0.2 < ends[-1]["cross_after_start"] < 0.8


@pytest.mark.realtime
def test_away_from_home_holds_with_hold_away(tree_file, tmp_path, robot):
    q0 = robot.home + np.array([0.4, 0.0, 0.0, 0.0, 0.0, 0.0])
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "tree", q0=q0, extra=("--hold-away",))
    try:  # the daemon has seen the arm away from home before the throw
        assert until(lambda: run.status[-1].get("away_from_home"), 10.0, poll=0.02)
        _throw(run)  # ignored: the arm is not where the planner starts from
        time.sleep(0.8)
        status = run.status[-1]
        hist = run.sim.history()
    finally:
        code, err = run.stop()
    assert code == 0, err
    assert np.max(np.abs(hist.q - q0)) < 1e-6
    # not "idle": the contract's idle is at home and ready
    assert status["away_from_home"] and status["state"] == "fault" and status["throws"] == 0
    assert "--hold-away" in err


@pytest.mark.realtime
def test_go_home_moves_home_once_the_way_is_clear(tree_file, tmp_path, robot):
    q0 = robot.home + np.array([0.4, 0.0, 0.0, 0.0, 0.0, 0.0])
    run = DaemonRun(tree_file, tmp_path / "rec.h5", "tree", q0=q0)  # --go-home is the default
    try:
        deadline = time.time() + 8.0
        while time.time() < deadline and run.status[-1].get("way_home") != "clear":
            time.sleep(0.05)
        assert run.wait_state("idle", timeout=8.0)
        # the servo follows the last commands home: polled, no fixed wait
        until(lambda: np.allclose(run.sim.q, robot.home, atol=2e-3), 10.0, poll=0.02)
        status = run.status[-1]
        q_end = run.sim.history().q[-1]
    finally:
        code, err = run.stop()
    assert code == 0, err
    assert status["way_home"] == "clear" and not status["away_from_home"]
    np.testing.assert_allclose(q_end, robot.home, atol=2e-3)


def _robot_with_post(robot, kin, tmp_path, q_mid):
    """robot.toml plus a 10 cm post where the shield centre is at ``q_mid``."""
    from thinkfast.robot.model import load_robot

    src = robot.toml_path.parent
    dst = tmp_path / "irb1600"
    shutil.copytree(src, dst)
    centre = kin.shield(q_mid).centre
    with open(dst / "robot.toml", "a") as f:
        f.write(
            '\n[[cell]]\nname = "post"\nshape = "box"\nsize = [0.1, 0.1, 0.1]\n'
            f"xyz = [{centre[0]}, {centre[1]}, {centre[2]}]\n"
        )
    return load_robot(dst / "robot.toml")


def test_way_home_is_checked_against_the_cell(robot, kin, tmp_path, small_tree_015):
    from thinkfast.control.config import RunConfig
    from thinkfast.control.executor import Executor
    from thinkfast.control.way_home import WayHome
    from thinkfast.decide.tree_view import runtime_tree
    from thinkfast.robot.collision import CollisionChecker
    from thinkfast.tree.file import load_tree

    cfg = RunConfig()
    q0 = robot.home + np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    post = _robot_with_post(robot, kin, tmp_path, robot.home + np.array([0.5, 0, 0, 0, 0, 0]))
    rt = runtime_tree(load_tree(small_tree_015), robot, cfg)

    def make():
        return Executor(rt, robot, cfg, "naive")

    clear = WayHome(make, CollisionChecker(robot), q0, DT).run()
    assert clear.clear and 0.3 < clear.duration < 5.0 and clear.samples > 50
    blocked = WayHome(make, CollisionChecker(post), q0, DT).run()
    assert not blocked.clear and "post" in blocked.detail
    assert 0.0 < blocked.duration < clear.duration  # found on the way, not at the start
    # sliced: the same answer a little at a time, never past the deadline by much
    sliced = WayHome(make, CollisionChecker(post), q0, DT)
    steps = 0
    while sliced.step(time.perf_counter() + 1e-4) is None:
        steps += 1
    assert sliced.result == blocked and steps > 3


@pytest.mark.realtime
def test_log_format_json_gives_one_object_per_line(tree_file, tmp_path, robot):
    run = DaemonRun(
        tree_file, tmp_path / "rec.h5", "naive", q0=robot.home, extra=("--log-format", "json")
    )
    try:  # until the events the test looks for are logged (no fixed wait)
        words = ('"event": "egm_connected"', '"event": "controller_state"')
        assert until(lambda: all(w in daemon_log(run.proc) for w in words), 30.0, poll=0.02)
    finally:
        code, err = run.stop()
    assert code == 0, err
    lines = [json.loads(line) for line in err.splitlines() if line.strip()]
    events = {x.get("event"): x for x in lines}
    start = events["start"]["detail"]
    assert start["planner"] == "naive" and start["tree_config_sha256"]
    assert set(start["limits"]) >= {"v_max", "a_max", "j_max"} and "zenoh" in start
    assert "egm_connected" in events and "controller_state" in events


def test_scale_limits_scales_velocity_acceleration_and_jerk(robot):
    from thinkfast.daemon.cli import scale_limits

    slow = scale_limits(robot, 0.25)
    for name in ("v_max", "a_max", "j_max"):
        np.testing.assert_allclose(getattr(slow, name), 0.25 * getattr(robot, name))
    assert scale_limits(robot, 1.0) is robot
    assert dataclasses.replace(slow).home is robot.home
