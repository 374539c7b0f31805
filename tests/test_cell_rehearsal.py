"""docs/CELL.md section 0, rehearsed as written: the four command blocks are read from the doc
and every line is run as a process (``thinkfast-run --foxglove``, ``thinkfast-sim controller``,
``thinkfast-cell``, ``thinkfast-run status``), from first light in shadow to the first simulated
block, and that block again on a secured cell (``thinkfast-cell certs``, mutual TLS). The doc
cannot drift from what runs.

What the test changes in the doc's lines, and only that: the cell's ports (6510, 8080, 7447,
8765) become free ones, and so do the zenoh ports in the configurations ``thinkfast-cell certs``
writes (the daemon's 7447, the camera node's 7448 for its bridge): the test rewrites those
files' endpoints after the line that writes them (no endpoint option is added to a line);
programs that open zenoh sessions on their own without a ``--zenoh-config`` get the loopback
zenoh configuration (no multicast scouting: other daemons on a shared host stay out); the live
``thinkfast-run status`` draws once (``--once``) so that its output can be read; the default tree
is the compiled ``trees/irb1600_default.h5`` when the checkout has it, else the tests' small tree
(``trees/*.h5`` is not in the repository). Of the doc's three simulated throws at least one must
be blocked (both trees blocked all three on a loaded 2-core host), on the secured cell too.
Every block runs in the test's temporary directory (its ``cal.h5``, ``patch.toml``, ``cell/``).

Waits are for conditions, with generous time limits (a host 3x slower than an idle one): the
controller starts once the daemon logs ``serving EGM on`` (its loop runs: before it, the
simulated IRC5's session would be lost after the program's 2 s ``comm_timeout`` without an
answer), the RWS once ``thinkfast-cell state`` answers, the throws once the daemon answers EGM
and zenoh routes both ways (:meth:`thinkfast.sim.watchdog.Watchdog.wait_ready`). Every
process's output (the daemon's log, the controller's lines, each command's stdout and stderr)
is printed at the end of each test, so a failure shows it. The secured cell's status is read
through its viewer node's configuration (the test's own reads too), once while the throws run
(the camera's node is linked only while the thrower's session is open) and once after.
"""

from __future__ import annotations

import json
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.daemon_harness import free_port, until
from thinkfast.contract.zenoh_session import free_tcp_port
from thinkfast.sim.realtime import LOOPBACK_ZENOH, daemon_log, daemon_says, wait_port

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
DEFAULT_TREE = "trees/irb1600_default.h5"
START = 180.0  # s for a process to start serving (imports, tree, zenoh) on a slow host
pytestmark = pytest.mark.realtime


def rehearsal_blocks() -> list[list[str]]:
    """The command lines of docs/CELL.md section 0's code blocks (comments dropped)."""
    text = (ROOT / "docs" / "CELL.md").read_text(encoding="utf-8")
    section = text.split("## 0. Rehearsal on one machine", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"^```\n(.*?)^```", section, flags=re.M | re.S)
    return [[ln.split("  #", 1)[0].strip() for ln in b.splitlines() if ln.strip()] for b in blocks]


def test_the_doc_has_the_rehearsal_blocks():
    blocks = rehearsal_blocks()
    assert len(blocks) == 4
    progs = [{shlex.split(line)[0] for line in b} for b in blocks]
    assert progs[0] == progs[2] == progs[3] == {"thinkfast-run", "thinkfast-sim", "thinkfast-cell"}
    assert progs[1] == progs[0] | {"thinkfast-calib"}
    assert all(any("--foxglove" in line for line in blocks[i]) for i in (0, 2))
    assert all(any("--throws" in line for line in blocks[i]) for i in (1, 2, 3))
    secured = blocks[3]
    assert secured[0].startswith("thinkfast-cell certs ")
    assert all("--zenoh-config" in ln for ln in secured if ln.startswith("thinkfast-run"))
    assert any("tls/" in ln and "--zenoh-config" in ln for ln in secured)  # the camera node
    assert not any("tcp/" in ln or "--insecure-zenoh" in ln for ln in secured)


class Cell:
    """The processes of one block, on this test's ports."""

    def __init__(self, tree: Path, cwd: Path):
        self.cwd = cwd  # where the doc's relative files (cal.h5, patch.toml) go
        self.ports = {"6510": str(free_port()), "8080": str(free_tcp_port()),
                      "7447": str(free_tcp_port()), "8765": str(free_tcp_port()),
                      "7448": str(free_tcp_port())}  # fmt: skip
        self.tree = tree
        self.procs: list[tuple[subprocess.Popen, list[str]]] = []
        self.daemon: subprocess.Popen | None = None
        self.controller_lines: list[str] = []
        self.done: list[subprocess.CompletedProcess] = []  # the commands run, with their output
        self.log = ""  # the daemon's log, once stopped

    def free(self, text: str) -> str:
        """``text`` with the cell's ports replaced by this test's."""
        for port, mine in self.ports.items():
            text = re.sub(rf"(?<=:){port}\b|(?<= ){port}\b", mine, text)
        return text

    def args(self, line: str) -> list[str]:
        """The doc's line with this test's changes (module doc)."""
        args = [str(self.tree) if a == DEFAULT_TREE else a for a in shlex.split(self.free(line))]
        if args[:2] == ["thinkfast-run", "status"]:
            args += ["--once", "--timeout", "15"]
        if args[0] == "thinkfast-run" and "--zenoh-config" not in args:
            args += ["--zenoh-config", str(LOOPBACK_ZENOH)]
        return [str(BIN / args[0]), *args[1:]]

    def run(self, line: str) -> subprocess.CompletedProcess:
        """Start the daemon (``thinkfast-run --tree``) or the controller; run anything else
        (after ``thinkfast-cell certs DIR``, the ports in DIR's zenoh configurations)."""
        args = self.args(line)
        if "--tree" in args or args[1:2] == ["controller"]:
            return self._start(args)
        done = subprocess.run(args, capture_output=True, text=True, timeout=START, cwd=self.cwd)
        self.done.append(done)
        if args[1:2] == ["certs"] and done.returncode == 0:
            for conf in (self.cwd / args[2]).glob("*.json5"):
                conf.write_text(self.free(conf.read_text()))
        return done

    def _start(self, args: list[str]) -> subprocess.CompletedProcess:
        if args[1] == "controller":
            p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 cwd=self.cwd)  # fmt: skip
            threading.Thread(target=self._read, args=(p,), daemon=True).start()
        else:
            log = tempfile.TemporaryFile(mode="w+")  # a file: a full pipe would stall the daemon
            p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=log, text=True,
                                 cwd=self.cwd)  # fmt: skip
            p.log = log  # for daemon_log
            self.daemon = p
            self.procs.append((p, args))  # stopped and its log printed even if it never serves
            wait_port(p, int(self.ports["7447"]), timeout=START)
            assert daemon_says(p, "serving EGM on", START), "the daemon's loop did not start"
            return subprocess.CompletedProcess(args, 0, "", "")
        self.procs.append((p, args))
        return subprocess.CompletedProcess(args, 0, "", "")

    def _read(self, p: subprocess.Popen) -> None:
        for line in p.stdout:
            self.controller_lines.append(line.rstrip())

    def throw(
        self, lines: list[str], during: Callable[[], object] | None = None
    ) -> subprocess.CompletedProcess:
        """The block's daemon and throwing controller (its first two lines), then its
        ``thinkfast-cell start`` (the third); returns that once the throws are judged
        (``during()`` is called while they run, until then)."""
        self.run(lines[0])
        self.run(lines[1])
        self.url_ready()
        started = self.run(lines[2])
        assert started.returncode == 0, started.stderr
        ends = ("blocked ", "throws stopped")  # the summary, or the thrower's failure

        def judged() -> bool:
            if during is not None:
                during()
            return any(ln.startswith(ends) for ln in self.controller_lines)

        assert until(judged, 4 * START)
        assert any(ln.startswith("blocked ") for ln in self.controller_lines), "no summary"
        return started

    def url_ready(self) -> None:
        url = f"http://127.0.0.1:{self.ports['8080']}"
        state = [str(BIN / "thinkfast-cell"), "state", "--url", url]
        assert until(lambda: subprocess.run(state, capture_output=True).returncode == 0, START)

    def status(self, viewer: Path | None = None) -> dict:
        """The daemon's status over zenoh (``{}`` when none came): on loopback TCP, or as the
        secured cell's viewer node whose configuration is ``viewer``."""
        if viewer is None:
            how = ["--zenoh-connect", f"tcp/127.0.0.1:{self.ports['7447']}",
                   "--zenoh-config", str(LOOPBACK_ZENOH)]  # fmt: skip
        else:
            how = ["--zenoh-config", str(viewer)]
        out = subprocess.run(
            [str(BIN / "thinkfast-run"), "status", "--json", "--timeout", "5", *how],
            capture_output=True, text=True, timeout=START,
        )  # fmt: skip
        return json.loads(out.stdout)["thinkfast"]["status"] if out.returncode == 0 else {}

    def stop(self) -> tuple[list[int], str]:
        """SIGINT every process (as Ctrl-C); their exit codes and the daemon's log."""
        codes = []
        for p, _ in reversed(self.procs):
            p.send_signal(signal.SIGINT)
        for p, _ in self.procs:
            try:
                codes.append(p.wait(START))
            except subprocess.TimeoutExpired:
                p.kill()
                codes.append(-9)
        self.log = daemon_log(self.daemon) if self.daemon is not None else ""
        return codes, self.log

    def print_output(self) -> None:
        """Everything the block's processes said (pytest shows it when the test fails)."""
        for r in self.done:
            print(f"$ {shlex.join(r.args)}  -> exit {r.returncode}\n{r.stdout}{r.stderr}")
        print("--- the controller:", *self.controller_lines, sep="\n")
        print("--- the daemon's log:", self.log, sep="\n")


@pytest.fixture(scope="module")
def tree(small_tree_015) -> Path:
    default = ROOT / DEFAULT_TREE
    return default if default.exists() else small_tree_015


def _foxglove_topics(port: str) -> set[str]:
    pytest.importorskip("websocket")
    from tests.foxglove_client import advertised, connect

    ws = connect(int(port))
    try:
        return set(advertised(ws))
    finally:
        ws.close()


def test_first_light_in_shadow_as_the_doc_says(tree, tmp_path):
    pytest.importorskip("foxglove")
    lines, cell = rehearsal_blocks()[0], Cell(tree, tmp_path)
    out: dict[str, subprocess.CompletedProcess] = {}
    try:
        cell.run(lines[0])  # the daemon, --shadow --foxglove
        cell.run(lines[1])  # the simulated IRC5
        cell.url_ready()
        assert "/thinkfast/scene" in _foxglove_topics(cell.ports["8765"])
        seen: dict[str, dict] = {}

        def connected() -> bool:
            seen["on"] = cell.status()
            return bool(seen["on"].get("egm_connected"))

        for line in lines[2:]:
            if " start " in line:  # no session yet: the controller sends nothing
                seen["before"] = cell.status()
            if "status" in line:
                assert until(connected, START)
            out[line] = r = cell.run(line)
            assert r.returncode == 0, (line, r.stdout, r.stderr)
        assert until(lambda: cell.status().get("egm_connected") is False, START)
    finally:
        codes, log = cell.stop()
        cell.print_output()
    assert codes == [0, 0], log
    state, status = out[lines[2]].stdout, out[lines[4]].stdout
    assert "motoron" in state.replace(" ", "").lower() or "motors on" in state.lower(), state
    assert "stopped" in state.lower(), state  # RAPID not yet started
    assert "shadow" in status.lower() or "idle" in status.lower(), status
    # the status over zenoh, in a session: the controller's state and the shadow plan
    assert seen["before"]["egm_connected"] is False
    on = seen["on"]
    assert on["controller"]["motors_on"] and on["controller"]["rapid_running"]
    assert on["controller"]["mci_running"] and on["shadow"] is not None
    assert on["egm"]["replied"] > 0
    for word in ("foxglove on ws://", "egm_connected", "controller_state", "egm_lost",
                 '"tree_fingerprint"'):  # fmt: skip
        assert word in log, word
    said = "\n".join(cell.controller_lines)
    assert f"RWS on http://127.0.0.1:{cell.ports['8080']}" in said and "tf_status session" in said


def test_a_slow_recorded_session_and_its_calibration_as_the_doc_says(tree, tmp_path):
    lines, cell = rehearsal_blocks()[1], Cell(tree, tmp_path)
    try:
        cell.throw(lines)  # --speed-scale 0.2 --record cal.h5, --throws 2, cell start
        stopped = cell.run(lines[3])
        assert stopped.returncode == 0, stopped.stderr
    finally:
        codes, log = cell.stop()  # Ctrl-C: the record is complete
        cell.print_output()
    assert codes == [0, 0], log
    assert len([ln for ln in cell.controller_lines if ln.startswith("throw ")]) == 2
    calib, check = cell.run(lines[4]), cell.run(lines[5])
    print(calib.stdout, check.stdout, sep="\n")
    assert calib.returncode == 0, calib.stderr
    assert "controller lag" in calib.stdout and "no limit measured" in calib.stdout
    assert "max_acceleration[0] = 12.00: not measured" in calib.stdout  # robot.toml's, kept
    assert "controller_lag" in (tmp_path / "patch.toml").read_text()
    assert check.returncode == 0 and "patch.toml: OK" in check.stdout, check.stderr


def test_the_first_simulated_block_as_the_doc_says(tree, tmp_path):
    pytest.importorskip("foxglove")
    lines, cell = rehearsal_blocks()[2], Cell(tree, tmp_path)
    try:
        cell.throw(lines)  # full speed with --foxglove, --throws 3, cell start
        for line in lines[3:]:
            r = cell.run(line)
            assert r.returncode == 0, (line, r.stdout, r.stderr)
    finally:
        codes, log = cell.stop()
        cell.print_output()
    assert codes == [0, 0], log
    throws = [ln for ln in cell.controller_lines if ln.startswith("throw ")]
    assert len(throws) == 3, cell.controller_lines
    assert any("BLOCKED" in ln for ln in throws), throws  # the first simulated block
    assert "throw_start" in log and "egm_connected" in log
    # the status view drawn after the throws were judged: the throws the daemon counted (the
    # last may still be on its way home), the supervisor in the last one ended, the EGM
    # counters (not the rates or the session: a starved host may have lost it by then)
    view = next(r.stdout for r in cell.done if r.args[1:2] == ["status"])
    flat = " ".join(re.sub(r"[│|╭╮╰╯─]", " ", view).split())
    assert re.search(r"throws [123], node", flat), view
    assert re.search(r"intervened \d+ of \d+ ticks; last throw \d+ of \d+", flat), view
    assert re.search(r"EGM received [1-9]\d*, replied [1-9]\d*", flat), view


def test_the_first_block_on_a_secured_cell_as_the_doc_says(tree, tmp_path):
    lines, cell = rehearsal_blocks()[3], Cell(tree, tmp_path)
    viewer = tmp_path / "cell" / "viewer-status.json5"
    during: list[dict] = []  # statuses read while the throws run

    def watch() -> None:
        if not any("camera-base" in s.get("zenoh", {}).get("linked", ()) for s in during):
            during.append(cell.status(viewer))

    try:
        made = cell.run(lines[0])  # thinkfast-cell certs cell --viewer status
        assert made.returncode == 0, made.stderr
        cell.throw(lines[1:], during=watch)  # the TLS daemon, the camera node's throws, start
        for line in lines[4:]:
            r = cell.run(line)
            assert r.returncode == 0, (line, r.stdout, r.stderr)
        after = cell.status(viewer)
    finally:
        codes, log = cell.stop()
        cell.print_output()
    assert codes == [0, 0], log
    throws = [ln for ln in cell.controller_lines if ln.startswith("throw ")]
    assert len(throws) == 3, cell.controller_lines
    assert any("BLOCKED" in ln for ln in throws), throws  # the first block, secured
    # the status through the viewer node: a TLS session, the camera's node linked while it
    # threw, every detection admitted (none refused by the sender gate)
    linked = [s["zenoh"] for s in during if "camera-base" in s.get("zenoh", {}).get("linked", ())]
    assert linked, during
    assert linked[0]["auth"] == "tls" and "viewer-status" in linked[0]["linked"], linked[0]
    zen = after["zenoh"]
    assert zen["auth"] == "tls" and zen["links_opened"].get("camera-base", 0) >= 1, zen
    assert not zen["rejected"], zen
    assert "camera-base" in log and "throw_start" in log
    view = next(r.stdout for r in cell.done if r.args[1:2] == ["status"])
    flat = " ".join(re.sub(r"[│|╭╮╰╯─]", " ", view).split())
    assert re.search(r"throws [123], node", flat), view
