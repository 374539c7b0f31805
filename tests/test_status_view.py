"""``thinkfast-run status``: two real daemons on loopback zenoh (one served by the simulated
EGM controller over UDP, one with no controller), watched as JSON, as rich's recorded console,
and live in a terminal (tmux capture)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from rich.console import Console

from tests.conftest import TURNED_NAME, other_home_tree
from tests.daemon_harness import DaemonRun, free_port, until
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.daemon.status_cli import Listener
from thinkfast.daemon.status_view import StatusBoard, panel_rows, render, snapshot
from thinkfast.sim.realtime import start_daemon, wait_port

EXE = str(Path(sys.executable).parent / "thinkfast-run")


@pytest.fixture(scope="module")
def daemons(small_tree_015, robot, tmp_path_factory):
    """(endpoint A, endpoint B): daemon A served by a simulated controller, B by none."""
    run = DaemonRun(small_tree_015, tmp_path_factory.mktemp("a") / "a.h5", q0=robot.home,
                    prefix="lab_a")  # fmt: skip
    zb = free_tcp_port()
    b = start_daemon(small_tree_015, "naive", free_port(), zb, "lab_b", None, None)
    try:
        wait_port(b, zb)
        assert until(lambda: run.status[-1].get("egm_connected"), 10.0, poll=0.02)  # A served
        yield f"tcp/127.0.0.1:{run.zport}", f"tcp/127.0.0.1:{zb}"
    finally:
        b.terminate()
        b.wait(15)
        run.stop()


@pytest.mark.realtime
def test_json_snapshot_of_two_daemons(daemons):
    a, b = daemons
    out = subprocess.run(
        [EXE, "status", "--json", "--key-prefix", "lab_a", "--key-prefix", "lab_b",
         "--zenoh-connect", a, "--zenoh-connect", b, "--timeout", "10"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    snap = json.loads(out.stdout)
    assert set(snap) == {"lab_a", "lab_b"}
    sa, sb = snap["lab_a"]["status"], snap["lab_b"]["status"]
    assert sa["state"] == "idle" and sa["egm_connected"] and sa["planner"] == "tree"
    assert sb["egm_connected"] is False and sb["planner"] == "naive"
    assert snap["lab_a"]["egm_rates"]["replied"] > 0  # the controller is served
    assert snap["lab_b"]["egm_rates"].get("replied", 0) == 0
    assert not snap["lab_a"]["stale"]


@pytest.mark.realtime
def test_the_recorded_console_shows_state_controller_and_egm(daemons):
    a, b = daemons
    session = open_peer(connect=[a, b])
    board = StatusBoard()
    try:
        listener = Listener(session, ["lab_a", "lab_b", "lab_none"], board)
        deadline = time.time() + 10.0
        while time.time() < deadline and not all(
            p in board.daemons and board.daemons[p].rates for p in ("lab_a", "lab_b")
        ):
            listener.poll()
            time.sleep(0.05)
    finally:
        session.close()
    console = Console(record=True, width=140)
    console.print(render(board, time.time(), ("lab_a", "lab_b", "lab_none")))
    text = console.export_text()
    assert "lab_a/status" in text and "lab_b/status" in text
    assert "lab_none/status: no status heard yet" in text
    panel_a = text.split("lab_b/status")[0]
    assert "idle" in panel_a and "connected yes (127.0.0.1:" in panel_a
    assert "motors yes, MCI yes, RAPID yes" in panel_a
    assert "replied " in panel_a and "/s" in panel_a and "work p50" in panel_a
    assert "connected no" in text.split("lab_b/status")[1]


@pytest.mark.realtime
@pytest.mark.skipif(shutil.which("tmux") is None, reason="needs tmux")
def test_view_live_in_a_terminal(daemons, tmp_path):
    a, _ = daemons
    name = f"tf{uuid.uuid4().hex[:8]}"
    cmd = f"{EXE} status --key-prefix lab_a --zenoh-connect {a} --rate 4; echo EXIT=$?; sleep 30"
    subprocess.run(["tmux", "new-session", "-d", "-s", name, "-x", "150", "-y", "40", cmd],
                   check=True)  # fmt: skip
    try:
        screen = ""
        deadline = time.time() + 30.0
        while time.time() < deadline and "replied" not in screen.split("EGM rate")[-1][:40]:
            time.sleep(0.5)
            screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", name],
                                    capture_output=True, text=True).stdout  # fmt: skip
        assert "lab_a/status" in screen and "idle" in screen and "connected yes" in screen
        subprocess.run(["tmux", "send-keys", "-t", name, "C-c"], check=True)
        deadline = time.time() + 15.0
        while time.time() < deadline and "EXIT=" not in screen:
            time.sleep(0.3)
            screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", name],
                                    capture_output=True, text=True).stdout  # fmt: skip
        assert "EXIT=0" in screen
    finally:
        subprocess.run(["tmux", "kill-session", "-t", name], check=False)


def test_stale_exiting_and_missing_keys_are_shown():
    board = StatusBoard()
    board.update("x", {"stamp": 100.0, "state": "idle", "egm": {"replied": 0}}, 10.0)
    last = {"stamp": 100.5, "state": "fault", "egm": {"replied": 125}, "braking": True,
            "brake_reason": "deviation", "exiting": True}  # fmt: skip
    board.update("x", last, 10.5)
    snap = snapshot(board, 12.0)
    assert snap["x"]["stale"] and snap["x"]["egm_rates"]["replied"] == 250.0
    rows = dict(panel_rows(board.daemons["x"].status, board.daemons["x"].rates, 1.5))
    assert rows["state"] == "fault (braking: deviation) (exiting)"
    assert rows["status age"] == "1.50 s STALE" and rows["recorder"] == "-"
    assert rows["EGM rate"].startswith("replied 250/s")


def test_throws_supervisor_last_throw_and_cameras_are_shown():
    """The rows a lab reads after a throw: the throw count, the supervisor's interventions
    overall and in the last throw, and each extra camera's fusion counts (schema keys)."""
    status = {
        "stamp": 5.0, "state": "idle", "throws": 4, "node": 0, "planner": "tree",
        "interventions": {"ticks": 900, "intervened": 2,
                          "last_throw": {"ticks": 300, "intervened": 1}},
        "cameras": {"side": {"fused": 40, "inconsistent_camera": 0, "untrusted": 0,
                             "inconsistent": 1, "passed": 39}},
    }  # fmt: skip
    rows = dict(panel_rows(status, {}, 0.1))
    assert rows["throws"].startswith("4, node 0,")
    assert rows["supervisor"] == "intervened 2 of 900 ticks; last throw 1 of 300"
    assert rows["cameras"] == (
        "side: fused 40, inconsistent_camera 0, untrusted 0, inconsistent 1, passed 39"
    )
    first = {"ticks": 9, "intervened": 0, "last_throw": None}  # before a throw has ended
    before = dict(panel_rows({**status, "interventions": first}, {}, 0.1))
    assert before["supervisor"] == "intervened 0 of 9 ticks; last throw -"


@pytest.mark.realtime
def test_status_start_log_and_record_name_the_trees_robot_and_plane(tmp_path):
    """A tree compiled for another robot folder: ``thinkfast-run status``, the start log and the
    record name that robot (name, robot.toml), the tree's fingerprint and the plane."""
    from thinkfast.record.format import read_record
    from thinkfast.robot.model import load_robot
    from thinkfast.tree.file import load_tree, tree_fingerprint

    tree, toml = other_home_tree(tmp_path)
    robot, fp = load_robot(toml), tree_fingerprint(load_tree(tree))[:16]
    run = DaemonRun(tree, tmp_path / "rec.h5", q0=robot.home, prefix="lab_t")
    try:
        assert until(lambda: run.status[-1].get("egm_connected"), 60.0, poll=0.05)
        out = subprocess.run(
            [EXE, "status", "--json", "--key-prefix", "lab_t", "--zenoh-connect",
             f"tcp/127.0.0.1:{run.zport}", "--timeout", "10"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    finally:
        code, err = run.stop()
    assert code == 0, err
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)["lab_t"]["status"]
    named = {"name": TURNED_NAME, "robot_toml": str(toml.resolve()),
             "robot_toml_sha256": robot.toml_sha256[:16]}  # fmt: skip
    assert s["robot"] == named and s["tree_fingerprint"] == fp and s["plane_x"] == 0.8
    cell = dict(panel_rows(s, {}, 0.0))["cell"]
    assert f"robot {TURNED_NAME} ({toml.resolve()})" in cell and "plane x 0.8 m" in cell
    start = next(ln for ln in err.splitlines() if " start {" in ln)
    detail = json.loads(start.split(" start ", 1)[1])
    assert detail["robot"] == named and detail["tree_fingerprint"] == fp
    assert detail["plane_x"] == 0.8
    assert "away_from_home" not in err  # the arm starts at the tree's robot's home
    attrs = read_record(tmp_path / "rec.h5").attrs
    assert attrs["robot_name"] == TURNED_NAME and attrs["robot_toml"] == str(toml.resolve())
