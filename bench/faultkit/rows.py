"""One row per controller cycle: what the fault controller sent and the reply it applied.

Rows are float64 arrays of :data:`NCOL` columns (indices below), kept in chunks by
:class:`RowBuffer` so that a long soak run stays cheap. Times are wall-clock seconds
(``time.time()``), joints radians, velocities rad/s.
"""

from __future__ import annotations

import threading

import numpy as np

# scalar columns
K, TM, SEQNO, T_SEND, T_GRID, FLAGS = range(6)
N_VALID, N_BAD, N_NONFINITE, N_OUTSIDE, T_ARR, R_SEQNO, R_TM, R_MTYPE = range(6, 14)
Q_SENT = slice(14, 20)  # joints reported in the EgmRobot (absurd ones included)
Q_TRUE = slice(20, 26)  # the servo's joints when the EgmRobot left
QD_TRUE = slice(26, 32)  # the servo's velocity then
CMD_Q = slice(32, 38)  # the applied reply's planned joints (NaN: no reply this cycle)
CMD_QD = slice(38, 44)  # its speedRef joints
NCOL = 44

# flags (bit mask)
DUP = 1  # the EgmRobot went out twice
ABSURD = 2  # absurd joint values reported instead of the measured ones
FROZEN = 4  # the arm was not following
SEQ_RESET = 8  # seqno restarted from 0 at this message
PAUSE = 16  # a controller pause (loaded host) ended just before this cycle
SILENCE = 32  # a silence ended just before this cycle
MALFORMED = 64  # malformed datagrams followed the EgmRobot
LATE = 128  # this process woke more than half a cycle late (its own stall)
SEND_FAILED = 256


def new_row(k, tm, seqno, t_send, t_grid, flags, q_sent, q_true, qd_true) -> np.ndarray:
    """A row for a cycle just opened (no reply yet)."""
    row = np.full(NCOL, np.nan)
    row[[K, TM, SEQNO, T_SEND, T_GRID, FLAGS]] = (k, tm, seqno, t_send, t_grid, flags)
    row[[N_VALID, N_BAD, N_NONFINITE, N_OUTSIDE]] = 0.0
    row[Q_SENT], row[Q_TRUE], row[QD_TRUE] = q_sent, q_true, qd_true
    return row


def set_reply(row: np.ndarray, t_arr, q, qd, seqno, tm, mtype) -> None:
    """Store the applied reply (arrival stamp [s], planned joints, speedRef, header)."""
    row[[T_ARR, R_SEQNO, R_TM, R_MTYPE]] = (t_arr, seqno, tm, mtype)
    row[CMD_Q], row[CMD_QD] = q, qd


class RowBuffer:
    """Thread-safe append-only rows; :meth:`take` hands over what was appended since."""

    def __init__(self):
        self._rows: list[np.ndarray] = []
        self._lock = threading.Lock()
        self.total = 0

    def append(self, row: np.ndarray) -> None:
        with self._lock:
            self._rows.append(row)
            self.total += 1

    def take(self) -> np.ndarray:
        """Rows appended since the last call, shape (N, NCOL)."""
        with self._lock:
            rows, self._rows = self._rows, []
        return np.array(rows).reshape(-1, NCOL)
