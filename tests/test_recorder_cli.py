"""``thinkfast-run --record`` checks the record path at start-up, before serving EGM."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from tests.conftest import compile_small_tree
from tests.daemon_harness import free_port
from thinkfast.contract.egm import encode_robot
from thinkfast.sim.realtime import daemon_log, start_daemon


@pytest.fixture(scope="module")
def tree_file(tmp_path_factory):
    return compile_small_tree(tmp_path_factory.mktemp("record_cli"), depth=1, spacing=0.5)


def _sysfs_refuses_files() -> bool:
    probe = Path("/sys/thinkfast-probe.h5")
    try:
        probe.touch()
    except OSError:
        return True
    probe.unlink()
    return False


@pytest.mark.parametrize("case", ["missing_directory", "read_only_directory"])
def test_an_unusable_record_path_stops_the_daemon_before_any_egm_reply(tree_file, tmp_path, case):
    """The real daemon, with a controller sending real EgmRobot messages from its start: it
    exits non-zero with one line on stderr naming the path, and never replies.

    The read-only directory is /sys: the tests run as root, and root writes into a chmod'ed
    directory anyway (permission bits do not bind it), whereas sysfs refuses to create files
    for everyone (EACCES, or EROFS where /sys is mounted read-only as in many containers). A
    read-only mount would need mount rights, which a container may not grant. (The other
    refusals, a file as parent or a directory as path, are tests/test_recorder.py's.)

    Not ``realtime``: the path is checked before the EGM socket is served, so no reply can
    come however slowly a loaded host starts the daemon; the wait only gives up (60 s)."""
    if case == "read_only_directory" and not _sysfs_refuses_files():
        pytest.skip("/sys accepts new files here")
    record = {
        "missing_directory": tmp_path / "missing" / "rec.h5",
        "read_only_directory": Path("/sys/thinkfast_rec.h5"),
    }[case]
    egm_port, zport = free_port(), free_port(socket.SOCK_STREAM)
    proc = start_daemon(tree_file, "tree", egm_port, zport, "thinkfast", record, None)
    replies = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ctrl:
        ctrl.bind(("127.0.0.1", 0))
        ctrl.setblocking(False)
        seq, deadline = 0, time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            ctrl.sendto(encode_robot(seq, 4 * seq, [0.0] * 6), ("127.0.0.1", egm_port))
            seq += 1
            time.sleep(0.004)
            try:
                replies.append(ctrl.recv(4096))
            except BlockingIOError:
                pass
        if proc.poll() is None:
            proc.kill()
        time.sleep(0.05)  # a last reply would be here by now
        try:
            replies.append(ctrl.recv(4096))
        except BlockingIOError:
            pass
    err = daemon_log(proc).strip().splitlines()
    assert proc.returncode not in (0, None), err
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert err[0].startswith(f"thinkfast-run: error: {record}: cannot record here"), err
    assert seq > 10 and replies == []  # EgmRobot messages were waiting; none was answered
    assert not record.exists()
