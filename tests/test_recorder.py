"""The flight recorder with its real writer process and real HDF5 files: every stream round trips,
the file is readable while recording, rows in flight stay bounded when the writer stalls, bad
rows never raise, start-up errors name the path, and the reader reads schema 1 (golden file) and
refuses unknown versions."""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import time
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from tests.conftest import ROOT, assert_one_line_error, run_cli
from tests.data.make_golden_record import ATTRS as GOLDEN_ATTRS
from tests.data.make_golden_record import golden_rows
from thinkfast.errors import RecorderError, RecordFileError
from thinkfast.record import recorder as recorder_mod
from thinkfast.record.format import MODES, read_detections, read_record
from thinkfast.record.recorder import Recorder

GOLDEN_V1 = ROOT / "tests" / "data" / "record_v1_golden.h5"


def _belief(rng):
    cov = rng.normal(size=(6, 6))
    return SimpleNamespace(t=float(rng.normal()), mean=rng.normal(size=6), cov=cov @ cov.T)


def _crossing(rng, ok=True):
    return SimpleNamespace(ok=ok, mean=rng.normal(size=3), cov=np.diag(rng.uniform(size=3)))


def _wait_written(rec: Recorder, n: int, timeout: float = 5.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rec.service()
        st = rec.status()
        if st["written"] >= n:
            return st
        time.sleep(0.02)
    raise AssertionError(f"writer did not report {n} rows: {rec.status()}")


def test_every_stream_round_trips_exactly(tmp_path):
    """Rows of all six streams come back bit for bit, with the attributes; raw payloads of equal
    length, an empty and a 100 kB payload, a NaN, an unknown mode (-1), seq None (-1), and event
    details with non-ASCII text and values JSON cannot hold (written as their str)."""
    rng = np.random.default_rng(3)
    path = tmp_path / "rec.h5"
    attrs = {"planner": "naive", "n": 7, "x": 0.5, "cfg": {"a": [1, 2]}, "flag": True}
    rec = Recorder(path, attrs)
    payloads = [b"same", b"size", b"", bytes(rng.integers(0, 256, 100_000, dtype=np.uint8))]
    egm, det, bel, dec, events = [], [], [], [], []
    for i in range(600):  # more than a batch of each table
        row = (1e9 + 0.004 * i, i, rng.normal(size=6), rng.normal(size=6), rng.normal(size=6))
        rec.egm(*row, i % 7 == 0)
        egm.append([row[0], i, *row[2], *row[3], *row[4], float(i % 7 == 0)])
    for i, p in enumerate(payloads):
        rec.raw(10.0 + i, p)
    for i in range(300):
        pos, seq = rng.normal(size=3), None if i % 5 == 0 else i
        rec.detection(20.0 + i, 19.9 + i, pos, seq)
        det.append([20.0 + i, 19.9 + i, *pos, -1 if seq is None else seq])
        b, c = _belief(rng), _crossing(rng, ok=i % 2 == 0)
        rec.belief(20.0 + i, b, c)
        bel.append([20.0 + i, b.t, *b.mean, *b.cov.ravel(), float(c.ok), *c.mean, *c.cov.ravel()])
        mode = "brake" if i == 3 else MODES[i % len(MODES)]
        rec.decision(20.0 + i, mode, i, np.nan if i == 4 else 0.25, 3)
        value = np.nan if i == 4 else 0.25
        dec.append([20.0 + i, -1 if mode == "brake" else MODES.index(mode), i, value, 3])
    details = [{"reason": "déviation", "joints": [1, 2]}, {"n": np.int64(5)}, {}]
    for i, d in enumerate(details):
        rec.event(30.0 + i, "brake" if i == 0 else f"kind{i}", d)
        events.append((30.0 + i, "brake" if i == 0 else f"kind{i}", d))
    rec.close()
    st = rec.status()
    total = len(egm) + len(payloads) + 3 * len(det) + len(events)
    assert st == {**st, "state": "closed", "rows": total, "written": total, "dropped": 0}
    r = read_record(path)
    assert r.version == 2 and r.complete is True
    assert r.attrs == attrs
    np.testing.assert_array_equal(r.tables["egm"], np.array(egm))
    np.testing.assert_array_equal(r.tables["detections"], np.array(det))
    np.testing.assert_array_equal(r.tables["beliefs"], np.array(bel))
    np.testing.assert_array_equal(r.tables["decisions"], np.array(dec))
    assert r.raw_payloads == payloads and r.raw_t.tolist() == [10.0, 11.0, 12.0, 13.0]
    assert [(e.t, e.kind) for e in r.events] == [(t, k) for t, k, _ in events]
    assert r.events[0].detail == details[0] and r.events[1].detail == {"n": "5"}
    assert read_detections(path)[1] == payloads


@pytest.mark.realtime
def test_the_file_is_a_readable_record_while_recording(tmp_path):
    """Before close, h5py and the reader open the file and see the rows of the last commit."""
    path = tmp_path / "rec.h5"
    rec = Recorder(path, {})
    assert read_record(path).complete is False  # readable from the start, empty
    for i in range(500):
        rec.egm(float(i), i, np.zeros(6), np.ones(6), np.zeros(6), False)
    _wait_written(rec, 500)
    with h5py.File(path, "r") as f:
        assert f["egm"].shape == (500, 21)
    r = read_record(path)
    assert r.complete is False and r.tables["egm"][:, 1].tolist() == list(range(500))
    rec.close()
    assert read_record(path).complete is True


def test_rows_in_flight_stay_bounded_and_drops_are_counted_when_the_writer_stalls(tmp_path):
    """With the writer stopped (SIGSTOP), 30000 egm rows (5 MB) are offered: the rows taken never
    exceed what the batch and the pipe hold, the rest are counted as dropped, the calls allocate
    almost nothing, and after the writer resumes the file holds exactly the rows taken, in
    order."""
    path = tmp_path / "rec.h5"
    rec = Recorder(path, {})
    q = np.zeros(6)
    os.kill(rec.writer_pid, signal.SIGSTOP)
    try:
        tracemalloc.start()
        for i in range(30_000):
            rec.egm(float(i), i, q, q, q, False)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        st = rec.status()
    finally:
        os.kill(rec.writer_pid, signal.SIGCONT)
    bound_rows = rec.in_flight_bytes // (21 * 8)
    assert 0 < st["rows"] <= bound_rows
    assert st["rows"] + st["dropped"] == 30_000 and st["dropped"] > 20_000
    assert peak < 256 * 1024, peak  # the pipe is kernel memory; the batches are preallocated
    rec.close()
    assert rec.status()["state"] == "closed"
    seq = read_record(path).tables["egm"][:, 1]
    assert seq.tolist() == list(range(st["rows"]))


def test_bad_rows_are_dropped_counted_and_logged_once_never_raised(tmp_path, caplog):
    """A row that cannot be recorded (wrong joint count, unencodable detail, a belief without
    arrays) costs that row only: counted, one warning per stream, recording goes on."""
    rec = Recorder(tmp_path / "rec.h5", {})
    circular: dict = {}
    circular["self"] = circular
    with caplog.at_level(logging.WARNING, logger="thinkfast.run"):
        for _ in range(3):
            rec.egm(1.0, 1, np.zeros(5), np.zeros(6), np.zeros(6), False)
            rec.event(1.0, "loop", circular)
            rec.belief(1.0, None, None)
        rec.egm(2.0, 2, np.zeros(6), np.zeros(6), np.zeros(6), False)
    assert rec.status()["dropped"] == 9 and rec.enabled
    assert len([r for r in caplog.records if "refused a" in r.getMessage()]) == 3
    rec.close()
    assert read_record(tmp_path / "rec.h5").tables["egm"][:, 0].tolist() == [2.0]


def test_an_off_recorder_takes_nothing_and_reports_off():
    rec = Recorder(None, {"a": 1})
    rec.egm(1.0, 1, np.zeros(6), np.zeros(6), np.zeros(6), False)
    rec.event(1.0, "x", {})
    rec.service()
    rec.close()
    assert not rec.enabled and rec.writer_pid is None
    assert rec.status() == {
        "state": "off", "rows": 0, "dropped": 0, "errors": 0, "path": None, "written": 0
    }  # fmt: skip


def _sys_dir() -> Path | None:
    """/sys: root cannot create files there (sysfs), read-only or not; None where it can."""
    probe = Path("/sys/thinkfast-probe.h5")
    try:
        probe.touch()
    except OSError:
        return Path("/sys")
    probe.unlink()
    return None


@pytest.mark.parametrize(
    "case, reason",
    [
        ("missing", "does not exist"),
        ("file_parent", "is not a directory"),
        ("directory", "it is a directory"),
        ("sys", "cannot create the file"),
    ],
)
def test_start_up_errors_are_one_line_naming_path_and_reason(tmp_path, case, reason):
    """The constructor refuses a path it cannot record to at once, before any writer starts."""
    (tmp_path / "afile").write_text("x")
    if case == "sys" and _sys_dir() is None:
        pytest.skip("/sys accepts new files here")
    path = {
        "missing": tmp_path / "no" / "rec.h5",
        "file_parent": tmp_path / "afile" / "rec.h5",
        "directory": tmp_path,
        "sys": Path("/sys/rec.h5"),
    }[case]
    with pytest.raises(RecorderError) as err:
        Recorder(path, {})
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and reason in msg, msg


def test_the_golden_schema_1_record_reads_with_its_known_values():
    """Records written by the schema-1 writer still read: same values, no events, complete
    unknown (None), empty streams as (0, width)."""
    r = read_record(GOLDEN_V1)
    rows = golden_rows()
    assert r.version == 1 and r.complete is None and r.events == []
    assert r.attrs == GOLDEN_ATTRS
    assert r.raw_payloads == [p for _, p in rows["raw"]] and r.raw_t.tolist() == [10.0, 10.02]
    assert r.tables["detections"].tolist() == [[10.0, 9.96, 7.46, 0.0, 1.5, 1.0]]
    assert r.tables["decisions"].tolist() == [[10.0, 1.0, 3.0, 0.625, 7.0]]
    assert r.tables["egm"][:, 1].tolist() == [100, 101, 102] and r.tables["egm"][2, 20] == 1.0
    assert r.tables["beliefs"].shape == (1, 57) and r.tables["beliefs"][0, 44] == 1.0
    assert read_detections(GOLDEN_V1)[1] == r.raw_payloads


def test_unknown_versions_other_formats_and_non_hdf5_files_are_refused(tmp_path):
    v3 = tmp_path / "v3.h5"
    shutil.copy(GOLDEN_V1, v3)
    with h5py.File(v3, "r+") as f:
        f.attrs["schema_version"] = 3
    tree = tmp_path / "tree.h5"
    with h5py.File(tree, "w") as f:
        f.attrs["format"] = "thinkfast-tree"
    text = tmp_path / "text.h5"
    text.write_text("hello")
    for path, needle in [
        (v3, "schema_version 3 is not supported (this reader knows 1, 2"),
        (tree, "format is 'thinkfast-tree', expected 'thinkfast-record'"),
        (text, "not a readable HDF5 file"),
    ]:
        with pytest.raises(RecordFileError) as err:
            read_record(path)
        assert str(err.value).startswith(f"{path}: {needle}"), str(err.value)


def test_replay_refuses_an_unknown_version_in_one_line(tmp_path):
    """``thinkfast-sim replay`` on a schema-3 file: one line naming the file and the version."""
    v3 = tmp_path / "v3.h5"
    shutil.copy(GOLDEN_V1, v3)
    with h5py.File(v3, "r+") as f:
        f.attrs["schema_version"] = 3
    proc = run_cli("thinkfast-sim", "replay", str(v3), timeout=60)
    assert_one_line_error(proc, str(v3), "schema_version 3 is not supported")


def test_status_keys_and_json(tmp_path):
    """The status is a JSON-able dict with the keys the daemon's status message carries."""
    rec = Recorder(tmp_path / "rec.h5", {})
    st = rec.status()
    assert set(st) == {"state", "rows", "dropped", "errors", "path", "written"}
    assert json.loads(json.dumps(st))["state"] == "recording"
    rec.close()
    rec.close()  # idempotent
    assert rec.status()["state"] == "closed" and recorder_mod.CLOSE_TIMEOUT <= 2.0
