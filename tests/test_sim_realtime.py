"""thinkfast-sim run against a running daemon (--egm/--zenoh): a daemon that dies mid-run is
noticed, and the run exits non-zero naming what went silent (real processes, real sockets); a
child's log read while it writes loses no line."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.daemon_harness import free_port, until
from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.sim.child_log import log_text
from thinkfast.sim.realtime import start_daemon, wait_port


def test_a_log_read_while_its_writer_writes_keeps_every_line(tmp_path):
    """The reader shares the file offset with the child writing through it: reading must not
    move it (a ``seek(0)`` there once put a daemon's line over the start of its log)."""
    n = 4000
    script = (
        "import sys\n"
        f"for i in range({n}):\n"
        '    sys.stderr.write(\'{"line": %d, "pad": "%s"}\\n\' % (i, \'x\' * 60))\n'
        "    sys.stderr.flush()\n"
    )
    with open(tmp_path / "log", "w+") as log:
        child = subprocess.Popen([sys.executable, "-c", script], stderr=log)
        reads = 0
        while child.poll() is None:
            log_text(log)
            reads += 1
        assert child.wait() == 0
        lines = log_text(log).splitlines()
    assert reads > 0
    assert [json.loads(ln)["line"] for ln in lines] == list(range(n))


@pytest.mark.realtime
def test_sim_run_exits_non_zero_when_its_daemon_dies(small_tree_015):
    egm, zport = free_port(), free_tcp_port()
    daemon = start_daemon(small_tree_015, "tree", egm, zport, "thinkfast", None, None)
    states: list[str] = []
    watch = None
    try:
        wait_port(daemon, zport)
        watch = open_peer(connect=[f"tcp/127.0.0.1:{zport}"])
        watch.declare_subscriber(
            keys.status("thinkfast"),
            lambda s: states.append(json.loads(s.payload.to_bytes())["state"]),
        )
        sim = subprocess.Popen(
            [str(Path(sys.executable).parent / "thinkfast-sim"), "run", "--tree",
             str(small_tree_015), "--throws", "6", "--egm", f"127.0.0.1:{egm}",
             "--zenoh", f"tcp/127.0.0.1:{zport}"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        # the first throw is under way (the daemon's status says so): then the daemon dies
        assert until(lambda: states and states[-1] in ("tracking", "executing"), 60.0, 0.01)
        daemon.send_signal(signal.SIGKILL)
        out, err = sim.communicate(timeout=60)
    finally:
        if watch is not None:
            watch.close()
        daemon.kill()
        daemon.wait(10)
    assert sim.returncode == 1, (out, err)
    line = err.strip().splitlines()[-1]
    assert line.startswith("thinkfast-sim: error: the daemon at EGM 127.0.0.1:")
    assert "stopped (no " in line and " of 6 throws" in line
    assert "blocked" not in out.split("\n")[-2]  # no summary of throws that never ran


@pytest.mark.realtime
def test_two_daemons_on_one_host_with_one_key_prefix_never_hear_each_other(
    small_tree_015, tmp_path, robot
):
    """Daemons started by the simulators and tests scout no peers by multicast: detections
    published to one reach only that one, though both use the key prefix ``thinkfast``."""
    import json

    from tests.daemon_harness import DaemonRun

    a = DaemonRun(small_tree_015, tmp_path / "a.h5", q0=robot.home)
    b = DaemonRun(small_tree_015, tmp_path / "b.h5", q0=robot.home)
    try:
        stamp = time.time() - 0.5
        for k in range(20):  # a ball standing still
            a.publish(json.dumps({"stamp": stamp + 0.02 * k, "position": [5.0, 0.1, 1.0],
                                  "frame": "camera", "seq": k + 1}).encode())  # fmt: skip
        deadline = time.time() + 20.0
        while time.time() < deadline and _counted(a.status[-1]["detections"]) < 20:
            time.sleep(0.05)
        time.sleep(0.5)  # what b would have heard has arrived by now
        heard_a, heard_b = a.status[-1]["detections"], b.status[-1]["detections"]
    finally:
        a.stop()
        b.stop()
    assert _counted(heard_a) == 20 and heard_a["accepted"] > 0
    assert _counted(heard_b) == 0


def _counted(d: dict) -> int:
    """Detections a daemon's status says it took, refused or dropped."""
    return d["accepted"] + sum(d["rejected"].values()) + sum(d["dropped"].values())
