"""The flight recorder when writing fails mid-run: a file size limit (EFBIG), a full tmpfs
(ENOSPC), a killed writer, a stuck writer at close. Each time: no exception, one error logged,
counted, recording stops, the caller keeps going, and the file is a readable partial record
holding exactly the rows of the writer's last commit; nothing else is left on the disk."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from thinkfast.record.format import read_record
from thinkfast.record.recorder import CLOSE_TIMEOUT, Recorder

# Records egm rows (seqno = 0, 1, 2, ...) and a raw payload every 10th, at ~2000 rows/s, calling
# service() as a daemon would, until recording fails, then goes on for 0.3 s; prints a summary.
CHILD = r"""
import json, logging, resource, signal, sys, time
import numpy as np
limit = int(sys.argv[2])
if limit:  # writes past the limit fail with EFBIG instead of killing the process
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from thinkfast.record.recorder import Recorder
errors = []
class Count(logging.Handler):
    def emit(self, record):
        if record.levelno >= logging.ERROR:
            errors.append(record.getMessage())
logging.getLogger("thinkfast.run").addHandler(Count())
rec = Recorder(sys.argv[1], {"planner": "tree"})
q = np.zeros(6)
i, t0, failed_at, slowest = 0, time.monotonic(), None, 0.0
while time.monotonic() - t0 < 20:
    for _ in range(10):
        c = time.perf_counter()
        rec.egm(float(i), i, q + i, q, q, False)
        if i % 10 == 0:
            rec.raw(float(i), b'{"seq": %d}' % i)
        rec.service()
        slowest = max(slowest, time.perf_counter() - c)
        i += 1
    time.sleep(0.005)
    if failed_at is None and rec.status()["state"] == "failed":
        failed_at = time.monotonic()
    if failed_at is not None and time.monotonic() - failed_at > 0.3:
        break
c = time.monotonic()
rec.close()
print(json.dumps({"status": rec.status(), "errors": errors, "offered": i,
                  "close_s": time.monotonic() - c, "slowest_s": slowest}))
"""


def _record_until_failure(path, limit: int = 0) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(path), str(limit)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _check_partial(path, out: dict) -> None:
    """The failure was reported once and the file holds exactly the committed rows, in order."""
    st = out["status"]
    assert st["state"] == "failed" and st["errors"] == 1, out
    assert len(out["errors"]) == 1 and str(path) in out["errors"][0], out["errors"]
    with h5py.File(path, "r") as f:  # plain h5py opens the partial record
        n_egm = f["egm"].shape[0]
    r = read_record(path)
    assert r.complete is False and n_egm > 0
    assert n_egm + len(r.raw_payloads) == st["written"]
    assert r.tables["egm"][:, 1].tolist() == list(range(n_egm))
    assert r.raw_payloads == [b'{"seq": %d}' % i for i in range(0, 10 * len(r.raw_payloads), 10)]


def test_a_file_size_limit_mid_run_leaves_the_last_commit_readable(tmp_path):
    """RLIMIT_FSIZE (inherited by the writer, SIGXFSZ ignored): the refused commit is rolled
    back, the file stays within the limit, no temporary file is left."""
    limit = 300_000
    out = _record_until_failure(tmp_path / "rec.h5", limit)
    assert "File too large" in out["errors"][0]
    _check_partial(tmp_path / "rec.h5", out)
    assert (tmp_path / "rec.h5").stat().st_size <= limit
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.h5"]


@pytest.fixture
def tiny_disk(tmp_path):
    """A 512 KiB tmpfs (skipped where mounting is not allowed, e.g. in some containers)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mount = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(disk)], capture_output=True
    )
    if mount.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mount.stderr.decode().strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_a_full_disk_mid_run_leaves_the_last_commit_readable_and_space_free(tiny_disk):
    """ENOSPC on a real full file system: the refused commit is truncated away, so the disk is
    not left full and holds only the record."""
    out = _record_until_failure(tiny_disk / "rec.h5")
    assert "No space left on device" in out["errors"][0]
    _check_partial(tiny_disk / "rec.h5", out)
    assert sorted(p.name for p in tiny_disk.iterdir()) == ["rec.h5"]
    free = os.statvfs(tiny_disk)
    assert free.f_bavail * free.f_frsize > 0


def _record_some(rec: Recorder, n: int, start: int = 0) -> None:
    q = np.zeros(6)
    for i in range(start, start + n):
        rec.egm(float(i), i, q, q, q, False)


@pytest.mark.realtime
def test_a_killed_writer_stops_the_recording_and_the_caller_goes_on(tmp_path, caplog):
    """SIGKILL of the writer process (as a native crash in HDF5 would end it): the next ship
    notices, logs one error, counts it; later calls are no-ops; the file holds the last commit."""
    path = tmp_path / "rec.h5"
    rec = Recorder(path, {})
    _record_some(rec, 300)
    deadline = time.monotonic() + 5
    while rec.status()["written"] < 300 and time.monotonic() < deadline:
        rec.service()
        time.sleep(0.02)
    os.kill(rec.writer_pid, signal.SIGKILL)
    time.sleep(0.1)
    with caplog.at_level(logging.ERROR, logger="thinkfast.run"):
        for k in range(20):
            _record_some(rec, 300, 300 * (k + 1))
            rec.service()
            time.sleep(0.01)
        rec.close()
    st = rec.status()
    assert st["state"] == "failed" and st["errors"] == 1 and not rec.enabled
    assert len(caplog.records) == 1 and "signal 9" in caplog.records[0].getMessage()
    assert read_record(path).tables["egm"][:, 1].tolist() == list(range(300))


@pytest.mark.realtime
def test_close_with_a_stuck_writer_is_bounded_and_keeps_the_last_commit(tmp_path):
    """A writer that never finishes (SIGSTOP) is killed after CLOSE_TIMEOUT; close returns in
    bounded time, reports the failure, and a second close is a no-op."""
    path = tmp_path / "rec.h5"
    rec = Recorder(path, {})
    _record_some(rec, 200)
    deadline = time.monotonic() + 5
    while rec.status()["written"] < 200 and time.monotonic() < deadline:
        rec.service()
        time.sleep(0.02)
    pid = rec.writer_pid
    os.kill(pid, signal.SIGSTOP)
    _record_some(rec, 1000, 200)
    t0 = time.monotonic()
    rec.close()
    elapsed = time.monotonic() - t0
    assert elapsed > CLOSE_TIMEOUT - 0.1  # it waited for the writer, then gave up on it
    st = rec.status()
    assert st["state"] == "failed" and st["errors"] == 1
    with pytest.raises(ProcessLookupError):  # killed and reaped
        os.kill(pid, 0)
    rec.close()
    assert rec.status() == st
    assert read_record(path).tables["egm"][:, 1].tolist() == list(range(200))
