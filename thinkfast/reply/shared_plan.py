"""Shared memory between the planner process and the reply process (``--reply-process``).

Two one-writer structures, neither of which ever blocks either side:

* :class:`Seqlock`: a block of float64 values (the plan) guarded by a sequence counter. The
  writer makes the counter odd, writes, makes it even; the reader copies and retries while the
  counter was odd or changed during the copy, so a torn write is never returned. Besides the
  block, one float64 *heartbeat* (the planner's last word, monotonic clock [s]): an aligned
  8-byte store, whole on every 64-bit CPU this runs on.
* :class:`RowRing`: fixed-width float64 rows (the replies and what the reply loop did), written
  by the reply process and read by the planner. The writer fills a row, then publishes the
  count; the reader copies the rows it has not seen and drops those the writer may have
  overwritten meanwhile (counted in ``lost``: the planner then plans from the newest row).

Both live in :mod:`multiprocessing.shared_memory` segments created by the planner process and
mapped by name in the reply process (directly, not through ``SharedMemory``: in Python 3.11 an
attaching process registers the segment with the resource tracker, which removes it when that
process ends).
"""

from __future__ import annotations

import mmap
import os
from multiprocessing import shared_memory

import numpy as np

from thinkfast.errors import ThinkfastError

_HEAD = 4  # float64 slots before the data: counter, heartbeat, spare, spare


class Seqlock:
    """A float64 block of ``size`` values behind a sequence counter (module doc).

    Args:
        size: values in the block.
        name: attach to this existing segment (None: create one).
    """

    def __init__(self, size: int, name: str | None = None):
        nbytes = 8 * (_HEAD + size)
        self.shm = _Segment(nbytes, name)
        self._owner = name is None
        self._counter = np.ndarray((1,), np.uint64, self.shm.buf, 0)
        self._beat = np.ndarray((1,), np.float64, self.shm.buf, 8)
        self._data = np.ndarray((size,), np.float64, self.shm.buf, 8 * _HEAD)
        if self._owner:
            self._counter[0] = 0
            self._beat[0] = -np.inf
            self._data[:] = np.nan

    @property
    def name(self) -> str:
        return self.shm.name

    @property
    def version(self) -> int:
        """The counter: even when no write is under way, +2 per write."""
        return int(self._counter[0])

    def write(self, values: np.ndarray) -> None:
        """Write ``values`` (at most ``size``) as one update."""
        n = len(values)
        self._counter[0] += 1  # odd: a write is under way
        self._data[:n] = values
        self._counter[0] += 1

    def read(self, tries: int = 100) -> tuple[int, np.ndarray] | None:
        """(version, a copy of the block) of a complete write, or None when every one of
        ``tries`` copies met a write under way (the caller keeps what it had)."""
        for _ in range(tries):
            v0 = int(self._counter[0])
            if v0 & 1:
                continue
            out = self._data.copy()
            if int(self._counter[0]) == v0:
                return v0, out
        return None

    def beat(self, t: float) -> None:
        """The writer's heartbeat: its clock ``t`` [s] now."""
        self._beat[0] = t

    @property
    def heartbeat(self) -> float:
        """The writer's last heartbeat [s] (-inf before the first)."""
        return float(self._beat[0])

    def close(self) -> None:
        """Detach; the creator also removes the segment."""
        self._counter = self._beat = self._data = None
        self.shm.close()


class RowRing:
    """``rows`` rows of ``width`` float64 values, one writer, one reader (module doc).

    Args:
        width: values per row.
        rows: ring length (a power of two is not required).
        name: attach to this existing segment (None: create one).
    """

    def __init__(self, width: int, rows: int = 4096, name: str | None = None):
        self.width, self.rows = width, rows
        nbytes = 8 * (_HEAD + width * rows)
        self.shm = _Segment(nbytes, name)
        self._owner = name is None
        self._count = np.ndarray((1,), np.uint64, self.shm.buf, 0)
        self._ring = np.ndarray((rows, width), np.float64, self.shm.buf, 8 * _HEAD)
        if self._owner:
            self._count[0] = 0
        self.seen = int(self._count[0])  # reader: rows taken so far
        self.lost = 0  # reader: rows overwritten before they were read

    @property
    def name(self) -> str:
        return self.shm.name

    @property
    def count(self) -> int:
        """Rows written since the start."""
        return int(self._count[0])

    def put(self, row: np.ndarray) -> None:
        """Append one row (``width`` values or fewer; the rest of the slot is left as it was)."""
        n = int(self._count[0])
        self._ring[n % self.rows, : len(row)] = row
        self._count[0] = n + 1  # published after the row is complete

    def take(self, limit: int | None = None) -> np.ndarray:
        """Copies of the rows written since the last call, oldest first, shape (k, width)
        (at most ``limit``, the oldest of them; overwritten rows are dropped and counted)."""
        end = int(self._count[0])
        start = max(self.seen, end - self.rows + 1)  # the slot being written next is spared
        self.lost += start - self.seen
        if limit is not None:
            end = min(end, start + limit)
        idx = np.arange(start, end) % self.rows
        out = self._ring[idx].copy()
        now = int(self._count[0])  # rows overwritten while copying are not trusted
        ok = np.arange(start, end) > now - self.rows
        if not ok.all():
            self.lost += int((~ok).sum())
            out = out[ok]
        self.seen = end
        return out

    def close(self) -> None:
        """Detach; the creator also removes the segment."""
        self._count = self._ring = None
        self.shm.close()


class _Segment:
    """A shared memory segment of ``nbytes``: created (``name`` None; removed by
    :meth:`close`) or mapped by name."""

    def __init__(self, nbytes: int, name: str | None):
        if name is None:
            try:
                self._shm = shared_memory.SharedMemory(create=True, size=nbytes)
            except OSError as e:  # e.g. /dev/shm full, or a file size limit (RLIMIT_FSIZE)
                raise ThinkfastError(
                    f"--reply-process: cannot create {nbytes} bytes of shared memory in /dev/shm "
                    f"for the plan hand-over: {e.strerror or e}"
                ) from None
            self.name, self.buf = self._shm.name, self._shm.buf
            return
        self._shm = None
        fd = os.open(f"/dev/shm/{name.lstrip('/')}", os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, nbytes)
        finally:
            os.close(fd)
        self.name, self.buf = name, memoryview(self._map)

    def close(self) -> None:
        self.buf = None
        if self._shm is not None:
            self._shm.close()
            self._shm.unlink()
        else:
            self._map.close()
