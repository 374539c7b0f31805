"""The flight recorder's row methods, called on the daemon's real-time EGM thread.

Each copies its row into a preallocated batch (:mod:`~thinkfast.record.wire`) and
returns; it never raises (a row it cannot take is dropped and counted, one warning per stream).
Shipping the batches is :class:`~thinkfast.record.recorder.Recorder`'s: a row method calls
``_ship`` only when its batch is full, or (except ``egm``) when the batches are MAX_AGE old.
"""

from __future__ import annotations

import json
import logging
import time

import numpy as np

from thinkfast.record.format import MODES
from thinkfast.record.wire import STREAM_ID, TableBatch, VarBatch

log = logging.getLogger("thinkfast.run")
TABLE_ROWS = 256  # rows per table batch
VAR_ROWS, VAR_BYTES = 64, 256 * 1024  # rows and bytes per variable-length batch (and per row)
MODE_INDEX = {m: float(i) for i, m in enumerate(MODES)}


class RowMethods:
    """Batches and the row methods; the recorder provides ``_ship``, ``_due`` and
    ``_retry_at`` (monotonic times of the next shipping by age and after a full pipe)."""

    dropped: int
    _due: float
    _retry_at: float
    _warned: set[str]

    def _ship(self) -> None:  # pragma: no cover - the recorder's
        raise NotImplementedError

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
