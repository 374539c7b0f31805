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

from tests.daemon_harness import free_port, until
from thinkfast.contract.zenoh_session import free_tcp_port

BIN = Path(sys.executable).parent
pytestmark = pytest.mark.realtime


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


def test_a_session_answered_late_is_kept_not_lost(robot, monkeypatch):
    """A sensor whose every answer comes after the controller stopped waiting for it (a daemon
    on a loaded host: the controller reads it at its next cycle, ``late``) is alive: the
    session outlives the program's comm_timeout. Before, only answers within their cycle
    counted, and the session was lost (``no EGM answer for 2.0 s: session lost`` in the
    rehearsal at load 12)."""
    assert _session_after(robot, monkeypatch, _Runner) == "session"


def test_a_controller_starved_by_its_host_keeps_its_session(robot, monkeypatch):
    """A simulated controller that sent nothing (its thread starved: the rehearsal at load
    15-18 lost its session 5 s in, before any throw, and the test waited 12 min for throws)
    blames no silence on the sensor; a sensor silent while the controller sends loses it."""
    starved = type("Starved", (_Runner,), {"sends": 0, "answers": 0})
    silent = type("Silent", (_Runner,), {"sends": 3, "answers": 0})  # ~one per 4 ms cycle
    assert _session_after(robot, monkeypatch, starved) == "session"
    assert _session_after(robot, monkeypatch, silent) == "lost"


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
