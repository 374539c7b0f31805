"""thinkfast-sim run against a running daemon (--egm/--zenoh): a daemon that dies mid-run is
noticed, and the run exits non-zero naming what went silent (real processes, real sockets)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.daemon_harness import free_port
from thinkfast.contract.zenoh_session import free_tcp_port
from thinkfast.sim.realtime import start_daemon, wait_port

pytestmark = pytest.mark.realtime


def test_sim_run_exits_non_zero_when_its_daemon_dies(small_tree_015):
    egm, zport = free_port(), free_tcp_port()
    daemon = start_daemon(small_tree_015, "tree", egm, zport, "thinkfast", None, None)
    try:
        wait_port(daemon, zport)
        sim = subprocess.Popen(
            [str(Path(sys.executable).parent / "thinkfast-sim"), "run", "--tree",
             str(small_tree_015), "--throws", "6", "--egm", f"127.0.0.1:{egm}",
             "--zenoh", f"tcp/127.0.0.1:{zport}"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        time.sleep(6.0)  # the first throw is under way
        daemon.send_signal(signal.SIGKILL)
        out, err = sim.communicate(timeout=60)
    finally:
        daemon.kill()
        daemon.wait(10)
    assert sim.returncode == 1, (out, err)
    line = err.strip().splitlines()[-1]
    assert line.startswith("thinkfast-sim: error: the daemon at EGM 127.0.0.1:")
    assert "stopped (no " in line and " of 6 throws" in line
    assert "blocked" not in out.split("\n")[-2]  # no summary of throws that never ran
