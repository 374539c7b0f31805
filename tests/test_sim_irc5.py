"""The simulated IRC5 (``thinkfast-sim controller``: RWS over HTTP, EGM over UDP): its EGM
session kept or lost by what the sensor answers, and a start refused with the motors off.
First light in shadow with every program a real process (docs/CELL.md section 7 step 1, the
status over zenoh in detail) is tests/test_cell_rehearsal.py's first test."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import HOME_J6, ROBOT_TOML, assert_one_line_error, other_home_tree, run_cli
from tests.daemon_harness import free_port, until
from thinkfast.contract.zenoh_session import free_tcp_port

BIN = Path(sys.executable).parent
START = 180.0  # s for a process to start serving (imports, tree, zenoh) on a slow host


def _run(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def _status(zport: int) -> dict:
    out = _run("thinkfast-run", "status", "--json", "--zenoh-connect",
               f"tcp/127.0.0.1:{zport}", "--timeout", "5")  # fmt: skip
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)["thinkfast"]["status"]


class _Runner:
    """The controller's UDP side, stood in: per ``cycle`` it sends ``sends`` EgmRobot and gets
    ``answers`` answers, each after its cycle (``late``: a loaded host)."""

    sends, answers = 1, 1

    def __init__(self, sim, target, keep_cycle=False):
        from thinkfast.sim.controller_runner import ExchangeStats

        self.stats = ExchangeStats()

    def start(self):
        return self

    def stop(self) -> None: ...

    def join(self, timeout=None) -> None: ...

    def cycle(self) -> None:
        self.stats.sent += self.sends
        self.stats.missed += self.sends
        self.stats.late += self.answers
        self.stats.answered += self.answers


def _session_after(robot, monkeypatch, runner: type) -> str:
    """tf_status after 10 comm_timeouts of ``runner``'s cycles, every 10 ms, in a session."""
    import time

    from thinkfast.sim import irc5 as irc5_module
    from thinkfast.sim.rws_server import ProgramTiming

    monkeypatch.setattr(irc5_module, "ControllerRunner", runner)
    timing = ProgramTiming(home_time=0.05, ramp_out=0.1, comm_timeout=0.1)
    irc5 = irc5_module.SimIrc5(("127.0.0.1", 9), q0=robot.home, timing=timing).start()
    try:
        with irc5.rws.lock:
            irc5.rws.execstate = "running"
        assert until(lambda: irc5.step() or irc5.rws.status() == "waiting", 30, poll=0.01)
        with irc5.rws.lock:
            irc5.rws.variables["T_ROB1/tf_start_request"] = "TRUE"
        assert until(lambda: irc5.step() or irc5.runner is not None, 30, poll=0.01)
        t_end = time.monotonic() + 10 * timing.comm_timeout
        while time.monotonic() < t_end and irc5.runner is not None:
            irc5.runner.cycle()
            irc5.step()
            time.sleep(0.01)
        return irc5.rws.status()
    finally:
        irc5.close()


@pytest.mark.realtime
def test_a_session_answered_late_is_kept_not_lost(robot, monkeypatch):
    """A sensor whose every answer comes after the controller stopped waiting for it (a daemon
    on a loaded host: the controller reads it at its next cycle, ``late``) is alive: the
    session outlives the program's comm_timeout. Before, only answers within their cycle
    counted, and the session was lost (``no EGM answer for 2.0 s: session lost`` in the
    rehearsal at load 12)."""
    assert _session_after(robot, monkeypatch, _Runner) == "session"


@pytest.mark.realtime
def test_a_controller_starved_by_its_host_keeps_its_session(robot, monkeypatch):
    """A simulated controller that sent nothing (its thread starved: the rehearsal at load
    15-18 lost its session 5 s in, before any throw, and the test waited 12 min for throws)
    blames no silence on the sensor; a sensor silent while the controller sends loses it."""
    starved = type("Starved", (_Runner,), {"sends": 0, "answers": 0})
    silent = type("Silent", (_Runner,), {"sends": 3, "answers": 0})  # ~one per 4 ms cycle
    assert _session_after(robot, monkeypatch, starved) == "session"
    assert _session_after(robot, monkeypatch, silent) == "lost"


@pytest.mark.realtime
def test_with_motors_off_the_simulated_controller_refuses_the_start_over_http():
    """docs/CELL.md section 0: ``thinkfast-sim controller --motors-off``, then ``thinkfast-cell
    start`` refuses (one line, exit 1) and the RAPID program stays stopped (real processes)."""
    rws = free_tcp_port()
    url = f"http://127.0.0.1:{rws}"
    irc5 = subprocess.Popen(
        [str(BIN / "thinkfast-sim"), "controller", "--motors-off", "--egm",
         f"127.0.0.1:{free_port()}", "--rws", f"127.0.0.1:{rws}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert until(lambda: _run("thinkfast-cell", "state", "--url", url).returncode == 0, 180)
        started = _run("thinkfast-cell", "start", "--url", url)
        state = json.loads(_run("thinkfast-cell", "state", "--url", url, "--json").stdout)
    finally:
        irc5.send_signal(signal.SIGINT)
        irc5.communicate(timeout=20)
    assert started.returncode == 1, started.stdout
    err = started.stderr.strip().splitlines()
    assert len(err) == 1 and "cannot start" in err[0] and "motors are off" in err[0], err
    assert state["rapid_execution"] == "stopped" and state["kit"]["tf_status"] != "session"


@pytest.fixture(scope="module")
def turned(tmp_path_factory):
    """(tree, robot.toml) of a robot whose home is not the default robot's."""
    return other_home_tree(tmp_path_factory.mktemp("turned"))


@pytest.mark.realtime
def test_the_simulated_controller_starts_at_the_trees_home(turned):
    """``thinkfast-sim controller --tree`` (its :func:`controller_cell`): the arm is the tree's
    robot, at that robot's home with its servo limits, so the daemon of that tree finds it at
    home (no ``away_from_home``) once the session runs (a real daemon, EGM over UDP)."""
    import threading

    import numpy as np

    from thinkfast.sim.irc5 import SimIrc5
    from thinkfast.sim.irc5_cli import controller_cell
    from thinkfast.sim.realtime import daemon_log, daemon_says, start_daemon, stop_daemon, wait_port

    tree, toml = turned
    robot, servo, plane = controller_cell(tree, None, None)
    assert robot.toml_path == toml.resolve() and robot.home[5] == HOME_J6
    assert servo.q_max == tuple(robot.q_upper) and servo.a_max == tuple(robot.a_max)
    assert plane[:2] == (0.8, str(tree)) and (plane.aim_y, plane.aim_z) == (
        (-0.9, 0.9),
        (0.25, 1.75),
    )
    egm, zport = free_port(), free_tcp_port()
    proc = start_daemon(tree, "tree", egm, zport, "thinkfast", None, None)
    irc5, stop, status = None, [], None
    try:
        wait_port(proc, zport, START)
        assert daemon_says(proc, "serving EGM on", START), "the daemon's loop did not start"
        irc5 = SimIrc5(("127.0.0.1", egm), servo=servo, q0=robot.home).start()
        np.testing.assert_array_equal(irc5.joints(), robot.home)
        loop = threading.Thread(target=irc5.run, args=(lambda: bool(stop),), daemon=True)
        loop.start()
        with irc5.rws.lock:
            irc5.rws.execstate = "running"
        assert until(lambda: irc5.rws.status() == "waiting", START, poll=0.05)
        with irc5.rws.lock:
            irc5.rws.variables["T_ROB1/tf_start_request"] = "TRUE"
        answered = lambda: irc5.runner is not None and irc5.runner.stats.answered >= 250  # noqa: E731
        assert until(answered, START, poll=0.05), "the daemon did not answer the session"
        status = _status(zport)
    finally:
        stop.append(1)
        if irc5 is not None:
            irc5.close()
        code = stop_daemon(proc)
    log = daemon_log(proc)
    assert code == 0, log
    assert "away_from_home" not in log, log
    assert status["away_from_home"] is False and status["state"] == "idle", status


def test_the_simulated_controller_refuses_a_run_config_naming_another_robot(turned, tmp_path):
    tree, _ = turned
    config = tmp_path / "run.toml"
    config.write_text(f'robot = "{ROBOT_TOML}"\n')
    egm = f"127.0.0.1:{free_port()}"
    out = run_cli("thinkfast-sim", "controller", "--tree", str(tree), "--config", str(config),
                  "--egm", egm, "--rws", "127.0.0.1:0", timeout=120)  # fmt: skip
    assert_one_line_error(out, f"{tree} was compiled for", str(ROBOT_TOML))
