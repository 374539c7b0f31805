"""Flight recorder: every detection (raw and accepted), belief, decision, EGM exchange and event.

The daemon's real-time thread calls the row methods (:meth:`Recorder.egm` on every reply,
``detection``, ``belief``, ``decision``, ``raw``, ``event``): each copies its row into a
preallocated batch (no system call; its cost: docs/BENCHMARKS.md, "Flight recorder"). Batches
go as frames (:mod:`~thinkfast.record.wire`) through a non-blocking pipe to a writer
process (:mod:`~thinkfast.record.writer`) that appends them to chunked HDF5 datasets and
commits the file every half second: the file on disk is a complete record at any moment
(docs/RECORD_FORMAT.md). Shipping costs a system call (docs/BENCHMARKS.md, bench/recorder.py),
so the daemon should call :meth:`Recorder.service` in idle time, which
ships every 0.1 s; else a row method ships when its batch is full (egm: every 256 rows) or,
except :meth:`Recorder.egm`, a second old.

Nothing here can stop or delay the daemon: a full pipe (the writer behind) drops rows and counts
them; memory stays bounded (:attr:`Recorder.in_flight_bytes`). A refused write (full disk, file
size limit, I/O error) or a dead writer is logged once ("thinkfast.run"), counted, and ends the
recording; the file keeps the writer's last commit. No method raises but the constructor, which
checks the path at once (:class:`RecorderError`). Not thread-safe: one thread calls them all.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from thinkfast.errors import RecorderError
from thinkfast.record.format import FORMAT, MODES, SCHEMA_VERSION, STREAMS, read_detections
from thinkfast.record.pipe import WriterGone, WriterPipe, check_target
from thinkfast.record.wire import STREAM_ID, TableBatch, VarBatch

__all__ = ["FORMAT", "SCHEMA_VERSION", "STREAMS", "Recorder", "RecorderError", "read_detections"]

log = logging.getLogger("thinkfast.run")
SERVICE_PERIOD = 0.1  # s: service() ships batches this often
MAX_AGE = 1.0  # s: a row method ships batches this old itself
RETRY = 0.1  # s before trying the pipe again after it was full (rows meanwhile dropped)
PIPE_BYTES = 1 << 20  # asked pipe capacity (Linux F_SETPIPE_SZ; 64 KiB if refused)
# s: a writer process not ready after START_TIMEOUT fails the start (a loaded host may take
# seconds to start a Python process); one not done CLOSE_TIMEOUT after close is killed
START_TIMEOUT, CLOSE_TIMEOUT = 60.0, 1.5
TABLE_ROWS = 256  # rows per table batch
VAR_ROWS, VAR_BYTES = 64, 256 * 1024  # rows and bytes per variable-length batch (and per row)
MODE_INDEX = {m: float(i) for i, m in enumerate(MODES)}


class Recorder:
    """Streams rows to ``path`` through a writer process (a no-op recorder when ``path`` is None).

    Args:
        path: the record file (created, or truncated if it exists), or None.
        attrs: attributes of the file (str/int/float as they are, others as JSON).

    Raises:
        RecorderError: the path cannot be recorded to (one line naming it and the reason).
    """

    def __init__(self, path: str | Path | None, attrs: dict | None = None):
        self.path = Path(path) if path else None
        self.state = "off"
        self.shipped = self.dropped = self.errors = self.written = 0
        self._pipe: WriterPipe | None = None
        self._warned: set[str] = set()
        self._due = self._retry_at = self._service_at = 0.0
        self._hot(False)
        if self.path is None:
            return
        check_target(self.path)
        try:
            self._pipe = WriterPipe(self.path, dict(attrs or {}), PIPE_BYTES, START_TIMEOUT)
        except RecorderError:
            self.path.unlink(missing_ok=True)  # created by check_target, or half by the writer
            raise
        self.state = "recording"
        self._hot(True)
        self._due = time.monotonic() + MAX_AGE

    @property
    def enabled(self) -> bool:
        """True while recording (off, failed and closed recorders ignore rows)."""
        return self.state == "recording"

    @property
    def writer_pid(self) -> int | None:
        """Process id of the writer (until close), for monitoring."""
        return self._pipe.proc.pid if self._pipe else None

    def move_writer(self, cpus: set[int]) -> None:
        """Run the writer process on ``cpus`` only (e.g. all but the EGM loop's after
        ``pin_thread``: it was started before). Never raises."""
        try:
            os.sched_setaffinity(self._pipe.proc.pid, cpus)
        except (AttributeError, OSError, ValueError):
            pass

    @property
    def in_flight_bytes(self) -> int:
        """Most bytes of rows between the row methods and the writer: batches and pipe (the
        writer adds at most ``writer.COMMIT_BYTES`` of uncommitted changes)."""
        pipe = self._pipe.capacity if self._pipe else 0
        return pipe + 8 * TABLE_ROWS * (6 + 57 + 5 + 21) + 2 * VAR_BYTES

    # -------------------------------------------------------------- rows (real-time thread)
    # Each row method copies its row into a preallocated batch (:mod:`~thinkfast.record.wire`)
    # and returns; it never raises (a row it cannot take is dropped and counted, one warning
    # per stream). It ships (``_ship``) only when its batch is full, or (except ``egm``) when
    # the batches are MAX_AGE old.
    def egm(self, t: float, seqno: int, q_fb, q_cmd, qd_cmd, braking: bool) -> None:
        """One EGM exchange: feedback [rad], setpoint sent [rad, rad/s], braking."""
        b = self._egm
        if b is None:
            return
        try:
            n = b.n
            if n == b.cap:
                return self._overflow()
            r = b.rows[n]
            r[0], r[1], r[2:8], r[8:14], r[14:20], r[20] = t, seqno, q_fb, q_cmd, qd_cmd, braking
            b.n = n + 1
            if n + 1 == b.cap:  # (not by age: the other row methods and service() do that)
                self._ship()
        except Exception as exc:  # noqa: BLE001 - never raise into the EGM loop
            self._bad_row("egm", exc)

    def detection(self, t: float, stamp: float, p: np.ndarray, seq: int | None) -> None:
        """An accepted detection: receive time and stamp [s], position in base [m], seq."""
        b = self._det
        if b is None:
            return
        try:
            if b.n == b.cap:
                return self._overflow()
            r = b.rows[b.n]
            r[0], r[1], r[2:5], r[5] = t, stamp, p, -1 if seq is None else seq
            b.n += 1
            self._after(b)
        except Exception as exc:  # noqa: BLE001
            self._bad_row("detections", exc)

    def belief(self, t: float, belief, crossing) -> None:
        """The filter belief (``.t``, ``.mean`` (6,), ``.cov`` (6, 6)) and its plane crossing
        (``.ok``, ``.mean`` (3,), ``.cov`` (3, 3)) at time ``t`` [s]."""
        b = self._bel
        if b is None:
            return
        try:
            if b.n == b.cap:
                return self._overflow()
            r = b.rows[b.n]
            r[0], r[1], r[2:8], r[8:44] = t, belief.t, belief.mean, np.ravel(belief.cov)
            r[44], r[45:48], r[48:57] = bool(crossing.ok), crossing.mean, np.ravel(crossing.cov)
            b.n += 1
            self._after(b)
        except Exception as exc:  # noqa: BLE001
            self._bad_row("beliefs", exc)

    def decision(self, t: float, mode: str, node: int, value: float, best_goal: int) -> None:
        """Planner state: mode (index in MODES, -1 if unknown), node, its value, best goal."""
        b = self._dec
        if b is None:
            return
        try:
            if b.n == b.cap:
                return self._overflow()
            b.rows[b.n] = (t, MODE_INDEX.get(mode, -1.0), node, value, best_goal)
            b.n += 1
            self._after(b)
        except Exception as exc:  # noqa: BLE001
            self._bad_row("decisions", exc)

    def raw(self, t: float, payload: bytes) -> None:
        """A detection payload as received at ``t`` [s]."""
        if self._raw is not None:
            try:
                self._var(self._raw, t, (bytes(payload),))
            except Exception as exc:  # noqa: BLE001
                self._bad_row("raw", exc)

    def event(self, t: float, kind: str, detail: dict) -> None:
        """Something the daemon reports at ``t`` [s]: ``kind`` and a JSON-able ``detail``
        (values JSON cannot hold are written as their ``str``)."""
        if self._ev is not None:
            try:
                d = json.dumps(detail, default=str, separators=(",", ":")).encode()
                self._var(self._ev, t, (str(kind).encode("utf-8", "replace"), d))
            except Exception as exc:  # noqa: BLE001 - e.g. a circular detail
                self._bad_row("events", exc)

    def _var(self, b: VarBatch, t: float, fields: tuple[bytes, ...]) -> None:
        size = sum(map(len, fields))
        if not b.fits(size):
            if size <= b.cap_bytes and time.monotonic() >= self._retry_at:
                self._ship()
            if not b.fits(size):
                self.dropped += 1
                return
        b.add(float(t), fields, size)
        self._after(b)

    def _after(self, b) -> None:
        if b.full() or time.monotonic() >= self._due:
            self._ship()

    def _overflow(self) -> None:
        self.dropped += 1
        if time.monotonic() >= self._retry_at:
            self._ship()

    def _bad_row(self, stream: str, exc: Exception) -> None:
        self.dropped += 1
        if stream not in self._warned:
            self._warned.add(stream)
            log.warning("flight record: refused a %s row (%s); such rows are dropped", stream, exc)

    def _hot(self, on: bool) -> None:
        """Create (or drop: the row methods then return at once) the batches."""
        if not on:
            self._raw = self._det = self._bel = self._dec = self._egm = self._ev = None
            self._batches: tuple = ()
            return
        s = STREAM_ID
        self._raw = VarBatch(s["raw"], VAR_ROWS, VAR_BYTES)
        self._det = TableBatch(s["detections"], 6, TABLE_ROWS)
        self._bel = TableBatch(s["beliefs"], 57, TABLE_ROWS)
        self._dec = TableBatch(s["decisions"], 5, TABLE_ROWS)
        self._egm = TableBatch(s["egm"], 21, TABLE_ROWS)
        self._ev = VarBatch(s["events"], VAR_ROWS, VAR_BYTES)
        self._batches = (self._raw, self._det, self._bel, self._dec, self._egm, self._ev)

    # -------------------------------------------------------------- idle time
    def service(self) -> None:
        """Ship the batches (every SERVICE_PERIOD) and read the writer's news. Call it in idle
        time: the row methods then never ship (one system call each time); without it they ship
        when a batch is full or a second old."""
        if self.state != "recording":
            return
        try:
            now = time.monotonic()
            if now >= self._service_at:
                self._service_at = now + SERVICE_PERIOD
                self._ship()
                self._read_writer()
        except Exception as exc:  # noqa: BLE001
            self._fail(f"internal error: {exc!r}")

    def status(self) -> dict:
        """``state`` (off, recording, failed, closed), ``rows`` taken, ``dropped``, write
        ``errors``, ``path``, and ``written``: rows in the file as of the writer's last report."""
        batched = 0
        try:
            if self.state == "recording":
                self._read_writer()
            batched = sum(b.n for b in self._batches)
        except Exception as exc:  # noqa: BLE001
            self._fail(f"internal error: {exc!r}")
        return {
            "state": self.state,
            "rows": self.shipped + batched,
            "dropped": self.dropped,
            "errors": self.errors,
            "path": str(self.path) if self.path else None,
            "written": self.written,
        }

    def close(self, timeout: float = CLOSE_TIMEOUT) -> None:
        """Ship what is left, let the writer close the file and wait for it, at most
        ``timeout`` [s] (then kill it: the file keeps its last commit). Idempotent; never raises.
        The daemon keeps the default (a prompt stop); offline writers may wait longer."""
        pipe, self._pipe = self._pipe, None
        if pipe is None:
            return
        try:
            deadline = time.monotonic() + timeout
            while self.state == "recording" and (pipe.tail or any(b.n for b in self._batches)):
                self._ship(pipe)
                if time.monotonic() >= deadline:
                    break
                pipe.wait_writable(0.01)
            if self.state == "recording":
                lost = sum(b.n for b in self._batches)
                self.shipped += lost
                self.dropped += lost
                self._hot(False)
                final = pipe.finish(deadline)
                self._news([final])
                if "closed" in final:
                    self.state = "closed"
                else:
                    self._fail(final.get("failed", "writer ended without closing the file"))
            else:
                pipe.finish(time.monotonic() + 0.5)
        except Exception as exc:  # noqa: BLE001
            self._fail(f"internal error while closing: {exc!r}")
            pipe.kill()
        finally:
            self._hot(False)

    # -------------------------------------------------------------- plumbing
    def _ship(self, pipe: WriterPipe | None = None) -> None:
        """Send the non-empty batches that fit into the pipe now (one system call, no wait)."""
        pipe = pipe or self._pipe
        now = time.monotonic()
        try:
            todo = [b for b in self._batches if b.n]
            taken = pipe.send([b.parts() for b in todo]) if todo else 0
            for b in todo[:taken]:
                self.shipped += b.n
                b.clear()
            if taken < len(todo) or (pipe.tail and not pipe.send_tail()):
                self._due = self._retry_at = now + RETRY
                return
        except WriterGone as exc:
            self._fail(self._news(pipe.read()) or str(exc))
            return
        self._due = now + MAX_AGE

    def _read_writer(self) -> None:
        pipe = self._pipe
        failed = self._news(pipe.read())
        if failed or pipe.proc.poll() is not None:
            self._fail(failed or pipe.death("writer gone"))

    def _news(self, msgs: list[dict]) -> str | None:
        """Take the writer's messages; returns its failure message, if one."""
        failed = None
        for m in msgs:
            self.written = int(m.get("written", self.written))
            failed = m.get("failed", failed)
        return failed

    def _fail(self, reason: str) -> None:
        """Stop recording (once): log, count, drop the batches; the writer is reaped at close."""
        if self.state != "recording":
            return
        self.state = "failed"
        self.errors += 1
        lost = sum(b.n for b in self._batches)
        self.shipped += lost  # taken, then lost: counted in rows and in dropped
        self.dropped += lost
        self._hot(False)
        log.error(
            "flight record %s: %s; recording stopped (%d rows in the file, %d dropped)",
            self.path, reason, self.written, self.dropped,
        )  # fmt: skip
