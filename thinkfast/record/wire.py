"""Frames from the recorder (daemon process) to its writer process, over a pipe.

A frame is a 12-byte header (stream id u8, 3 pad bytes, rows u32, body bytes u32, little
endian) and a body. Stream ids index :data:`~thinkfast.record.format.STREAMS`; id 255 is
the opening frame (JSON: the file's attributes). Bodies:

- a table (``width`` > 0): ``rows x width`` float64, row-major;
- variable-length rows with ``k`` byte fields (``raw``: payload; ``events``: kind, detail):
  ``rows`` float64 times, ``rows x k`` uint32 field lengths (row-major), then the fields' bytes
  in the same order.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np

from thinkfast.record.format import STREAMS

HEADER = struct.Struct("<BxxxII")
OPEN_ID = 255
FIELDS = {"raw": 1, "events": 2}  # byte fields of the variable-length streams
STREAM_ID = {s.name: i for i, s in enumerate(STREAMS)}


def open_frame(attrs: dict) -> bytes:
    """The first frame: the file's attributes (JSON-able values)."""
    body = json.dumps(attrs, default=str).encode()
    return HEADER.pack(OPEN_ID, 0, len(body)) + body


def table_frame(sid: int, rows: np.ndarray) -> bytes:
    """A frame of table rows, shape (n, width) float64."""
    body = np.ascontiguousarray(rows, dtype="<f8").tobytes()
    return HEADER.pack(sid, len(rows), len(body)) + body


def varlen_frame(sid: int, t: list[float], fields: list[tuple[bytes, ...]]) -> bytes:
    """A frame of variable-length rows: times [s] and one tuple of byte fields per row."""
    n = len(t)
    lengths = np.fromiter((len(b) for row in fields for b in row), dtype="<u4", count=-1)
    body = b"".join(
        (np.asarray(t, dtype="<f8").tobytes(), lengths.tobytes(), *(b for r in fields for b in r))
    )
    return HEADER.pack(sid, n, len(body)) + body


def decode_table(body: bytes, rows: int, width: int) -> np.ndarray:
    """Rows of a table frame, shape (rows, width)."""
    return np.frombuffer(body, dtype="<f8").reshape(rows, width)


def decode_varlen(body: bytes, rows: int, k: int) -> tuple[np.ndarray, list[list[bytes]]]:
    """Times (rows,) and, per field, the list of its ``rows`` byte strings."""
    t = np.frombuffer(body, dtype="<f8", count=rows)
    lengths = np.frombuffer(body, dtype="<u4", count=rows * k, offset=8 * rows).reshape(rows, k)
    pos = 8 * rows + 4 * rows * k
    if pos + int(lengths.sum()) != len(body):
        raise ValueError("variable-length frame: lengths do not add up to the body")
    fields: list[list[bytes]] = [[] for _ in range(k)]
    for row in lengths.tolist():
        for j, n in enumerate(row):
            fields[j].append(body[pos : pos + n])
            pos += n
    return t, fields


def read_exact(fd: int, n: int) -> bytes | None:
    """Read exactly ``n`` bytes from a blocking descriptor; None at end of file."""
    chunks, left = [], n
    while left:
        b = os.read(fd, min(left, 1 << 20))
        if not b:
            return None
        chunks.append(b)
        left -= len(b)
    return b"".join(chunks)


def read_frame(fd: int) -> tuple[int, int, bytes] | None:
    """The next frame (stream id, rows, body) from a blocking descriptor; None at end of file
    (also in the middle of a frame: the sender stopped)."""
    head = read_exact(fd, HEADER.size)
    if head is None:
        return None
    sid, rows, size = HEADER.unpack(head)
    body = read_exact(fd, size) if size else b""
    return None if body is None else (sid, rows, body)


class FrameSplitter:
    """Cuts a byte stream into frames (stream id, rows, body); keeps an incomplete end."""

    def __init__(self):
        self.buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        self.buf += data
        frames, pos = [], 0
        while len(self.buf) - pos >= HEADER.size:
            sid, rows, size = HEADER.unpack_from(self.buf, pos)
            end = pos + HEADER.size + size
            if end > len(self.buf):
                break
            frames.append((sid, rows, bytes(self.buf[pos + HEADER.size : end])))
            pos = end
        del self.buf[:pos]
        return frames


class TableBatch:
    """Rows of a table waiting to be shipped: a preallocated (cap, width) float64 array over a
    buffer whose byte view is kept, so that a frame's body is a slice of it (no copy)."""

    __slots__ = ("sid", "rows", "n", "cap", "row_bytes", "view")

    def __init__(self, sid: int, width: int, cap: int):
        buf = bytearray(8 * width * cap)
        self.sid, self.n, self.cap, self.row_bytes = sid, 0, cap, 8 * width
        self.rows = np.frombuffer(buf, dtype="<f8").reshape(cap, width)
        self.view = memoryview(buf)

    def full(self) -> bool:
        return self.n >= self.cap

    def parts(self) -> tuple[bytes, memoryview]:
        """The frame of the batched rows as (header, body); the body is a view of the batch."""
        size = self.n * self.row_bytes
        return HEADER.pack(self.sid, self.n, size), self.view[:size]

    def clear(self) -> None:
        self.n = 0


class VarBatch:
    """Variable-length rows waiting to be shipped, at most ``cap`` rows and ``cap_bytes``."""

    __slots__ = ("sid", "t", "fields", "n", "nbytes", "cap", "cap_bytes")

    def __init__(self, sid: int, cap: int, cap_bytes: int):
        self.sid, self.cap, self.cap_bytes = sid, cap, cap_bytes
        self.t: list[float] = []
        self.fields: list[tuple[bytes, ...]] = []
        self.n = self.nbytes = 0

    def fits(self, size: int) -> bool:
        return self.n < self.cap and self.nbytes + size <= self.cap_bytes

    def full(self) -> bool:
        return self.n >= self.cap

    def add(self, t: float, fields: tuple[bytes, ...], size: int) -> None:
        self.t.append(t)
        self.fields.append(fields)
        self.n += 1
        self.nbytes += size

    def parts(self) -> tuple[bytes, memoryview]:
        """The frame of the batched rows as (header, body)."""
        frame = varlen_frame(self.sid, self.t, self.fields)
        return frame[: HEADER.size], memoryview(frame)[HEADER.size :]

    def clear(self) -> None:
        self.t.clear()
        self.fields.clear()
        self.n = self.nbytes = 0
