"""``thinkfast-cell`` through the real abb-robot-client against the fake RWS controller.

Real HTTP with digest authentication on loopback (thinkfast/sim/rws_server.py); the fake runs
the kit's RAPID program as a state machine, so start/stop are judged by what the program does.
"""

from __future__ import annotations

import json
import socket

import pytest

pytest.importorskip("abb_robot_client.rws")

from thinkfast.cell.cli import main  # noqa: E402
from thinkfast.sim.rws_server import FakeRwsController, ProgramTiming  # noqa: E402


@pytest.fixture
def fake():
    with FakeRwsController() as ctrl:
        yield ctrl


def run(capsys, *argv: str) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``thinkfast-cell ARGV``."""
    with pytest.raises(SystemExit) as exc:
        main(list(argv))
    out = capsys.readouterr()
    return int(exc.value.code), out.out, out.err


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("thinkfast-cell: error: "), err
    assert "Traceback" not in err
    return lines[0]


def posts(ctrl: FakeRwsController) -> list[str]:
    return [path for method, path in ctrl.requests if method == "POST"]


def test_state_table_and_json(fake, capsys):
    fake.ctrlstate, fake.opmode, fake.speedratio = "motoroff", "MANR", 25
    code, out, err = run(capsys, "state", "--url", fake.url)
    assert code == 0, err
    assert "off (motoroff)" in out and "manual reduced speed (MANR)" in out
    assert "stopped" in out and "25 %" in out and "T_ROB1" in out
    assert "tf_start_request  FALSE" in out

    code, out, err = run(capsys, "state", "--url", fake.url, "--json")
    assert code == 0, err
    snap = json.loads(out)
    assert snap["motors_on"] is False and snap["auto"] is False
    assert snap["operation_mode"] == "MANR" and snap["rapid_execution"] == "stopped"
    assert snap["speed_ratio_percent"] == 25.0
    assert snap["tasks"][0]["name"] == "T_ROB1" and snap["tasks"][0]["motion"] is True
    assert snap["kit"]["tf_start_request"] is False and snap["kit"]["tf_stop_request"] is False
    assert posts(fake) == []  # reading changes nothing


@pytest.mark.parametrize(
    ("opmode", "ctrlstate", "expected"),
    [
        ("MANR", "motoron", ["operation mode is manual reduced speed (MANR), needs auto"]),
        ("AUTO", "motoroff", ["motors are off (motoroff), needs motors on"]),
        ("MANR", "guardstop", ["needs auto", "motors are off (guard stop) (guardstop)"]),
    ],
)
def test_start_refused_in_manual_mode_or_with_motors_off(fake, capsys, opmode, ctrlstate, expected):
    fake.opmode, fake.ctrlstate = opmode, ctrlstate
    code, _, err = run(capsys, "start", "--url", fake.url)
    assert code == 1
    line = one_error_line(err)
    assert "cannot start" in line
    for phrase in expected:
        assert phrase in line
    assert fake.execstate == "stopped" and posts(fake) == []


def test_start_then_stop_changes_the_state(fake, capsys):
    code, out, err = run(capsys, "start", "--url", fake.url)
    assert code == 0, err
    assert "RAPID started (T_ROB1)" in out and "EGM session running" in out
    assert fake.execstate == "running" and fake.status() == "session"
    assert fake.var("tf_start_request") == "FALSE"  # taken by the program

    code, out, _ = run(capsys, "state", "--url", fake.url, "--json")
    snap = json.loads(out)
    assert snap["rapid_execution"] == "running" and snap["kit"]["tf_status"] == "session"

    code, out, err = run(capsys, "start", "--url", fake.url)  # a second start does nothing
    assert code == 0 and "already running" in out, err

    code, out, err = run(capsys, "stop", "--url", fake.url)
    assert code == 0, err
    assert "EGM session ended (tf_status waiting)" in out
    assert fake.execstate == "running" and fake.status() == "waiting"

    code, out, err = run(capsys, "stop", "--url", fake.url, "--halt")
    assert code == 0, err
    assert "no EGM session running" in out and "RAPID stopped" in out
    assert fake.execstate == "stopped"
    assert "rw/rapid/execution" in posts(fake)


def test_start_waits_for_the_program_so_the_request_is_not_lost(capsys):
    # the program clears tf_start_request after its home move: a request set before it is lost
    with FakeRwsController(timing=ProgramTiming(home_time=0.4)) as fake:
        code, out, err = run(capsys, "start", "--url", fake.url)
        assert code == 0, err
        assert fake.status() == "session"


def test_stop_halt_during_a_session_waits_for_the_ramp_out(fake, capsys):
    assert run(capsys, "start", "--url", fake.url)[0] == 0
    code, out, err = run(capsys, "stop", "--url", fake.url, "--halt")
    assert code == 0, err
    assert "EGM session ended (tf_status waiting); RAPID stopped" in out
    assert fake.execstate == "stopped" and fake.status() == "waiting"


def test_resetpp_only_when_stopped_and_restarts_from_main(fake, capsys):
    assert run(capsys, "start", "--url", fake.url)[0] == 0
    code, _, err = run(capsys, "start", "--url", fake.url, "--resetpp")
    assert code == 1 and "--resetpp needs RAPID stopped" in one_error_line(err)

    assert run(capsys, "stop", "--url", fake.url, "--halt")[0] == 0
    code, out, err = run(capsys, "start", "--url", fake.url, "--resetpp")
    assert code == 0, err
    assert "program pointer reset to main" in out and fake.status() == "session"
    assert "rw/rapid/execution" in posts(fake)


def test_a_restart_from_main_does_not_lose_the_request_to_its_stale_waiting(capsys):
    """After ``stop --halt`` tf_status still says "waiting" until the restarted program's first
    statement (0.3 s here): the request set on that stale value is cleared by the program's
    loop, and set again once the program waits."""
    with FakeRwsController(timing=ProgramTiming(start_delay=0.3)) as fake:
        assert run(capsys, "start", "--url", fake.url)[0] == 0
        assert run(capsys, "stop", "--url", fake.url, "--halt")[0] == 0
        assert fake.status() == "waiting" and fake.execstate == "stopped"
        code, out, err = run(capsys, "start", "--url", fake.url, "--resetpp", "--wait", "5")
        assert code == 0, err
        assert "EGM session running" in out and fake.status() == "session"
        sets = [p for m, p in fake.requests if m == "POST" and "tf_start_request" in p]
        assert len(sets) == 3  # the first start, the stale "waiting", the program's own
        assert fake.var("tf_start_request") == "FALSE"  # taken by the program


def test_lost_session_is_one_line(fake, capsys):
    fake.egm_peer = False  # thinkfast-run silent: the module's ERR_UDPUC_COMM handler stops
    code, _, err = run(capsys, "start", "--url", fake.url)
    assert code == 1
    assert "session was lost" in one_error_line(err) and "thinkfast-run" in err
    assert fake.execstate == "stopped" and fake.status() == "lost"


def test_missing_kit_shown_in_state_and_refused_by_start(fake, capsys):
    del fake.variables["T_ROB1/tf_status"]
    code, out, _ = run(capsys, "state", "--url", fake.url)
    assert code == 0 and "tf_status         (not found)" in out
    code, _, err = run(capsys, "start", "--url", fake.url)
    assert code == 1 and "ThinkfastEGM.mod" in one_error_line(err)


def test_unreachable_url_is_one_line(capsys):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, _, err = run(capsys, "state", "--url", f"http://127.0.0.1:{port}")
    assert code == 1
    line = one_error_line(err)
    assert f"127.0.0.1:{port}" in line and "cannot connect (connection refused)" in line


def test_silent_controller_times_out_in_one_line(capsys):
    with socket.socket() as s:  # accepts connections (backlog) but never answers
        s.bind(("127.0.0.1", 0))
        s.listen(4)
        url = f"http://127.0.0.1:{s.getsockname()[1]}"
        code, _, err = run(capsys, "state", "--url", url, "--timeout", "0.3")
    assert code == 1
    assert "no answer within 0.3 s" in one_error_line(err)


def test_wrong_password_is_one_line(fake, capsys):
    code, _, err = run(capsys, "state", "--url", fake.url, "--password", "not-robotics")
    assert code == 1
    line = one_error_line(err)
    assert "authentication failed for user 'Default User' (HTTP 401)" in line
    assert fake.requests == []  # nothing got past the digest check

    code, _, err = run(capsys, "stop", "--url", fake.url, "--user", "Admin")
    assert code == 1 and "user 'Admin'" in one_error_line(err)


def test_https_url_is_refused_with_the_robotware_7_reason(capsys):
    code, _, err = run(capsys, "state", "--url", "https://192.168.125.1")
    assert code == 1
    assert "RWS 2.0" in one_error_line(err)


def test_rws_error_carries_the_controller_code(fake, capsys):
    # a start the pre-checks let through but the controller refuses: its code reaches the line
    fake.ctrlstate = "motoroff"
    from thinkfast.cell.client import Cell
    from thinkfast.errors import CellError

    cell = Cell(fake.url)
    with pytest.raises(CellError, match=r"start RAPID: RWS error -1073445001: .*motors off"):
        cell._call("start RAPID", cell.rws.start, "asis", ["T_ROB1"])
