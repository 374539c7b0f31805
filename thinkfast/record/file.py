"""The writer's side of a flight record: HDF5 through a file that only changes on commit.

HDF5 writes into a :class:`CommitFile`, which keeps every change in memory (pages of 4 KiB)
until :meth:`CommitFile.commit`. A commit first writes everything that lies past the end of
the file on disk (the only writes a full disk or a file size limit can refuse), syncs it, and
only then overwrites the pages inside the old end. A refused write is undone by truncating the
file back to its old end: the file on disk is the image of the previous commit, which was a
complete HDF5 file (committed right after ``H5Fflush``). HDF5 itself never sees an I/O error, so
its state never breaks (a failed ``H5Fclose`` followed by freeing its objects is what crashed
the schema-1 writer on a full disk, see docs/RECORD_FORMAT.md).

:class:`RecordFile` lays out the streams of :mod:`~thinkfast.record.format` as chunked
resizable datasets and appends the rows of each frame.
"""

from __future__ import annotations

import json
import os

import h5py
import numpy as np

from thinkfast.record.format import FORMAT, RESERVED_ATTRS, SCHEMA_VERSION, STREAMS
from thinkfast.record.wire import FIELDS, decode_table, decode_varlen

PAGE = 4096
CHUNK_BYTES = 64 * 1024  # target size of one HDF5 chunk of a table
VARLEN_CHUNK = 256  # rows per chunk of a variable-length stream


class CommitFile:
    """A seekable binary file (the subset h5py's ``fileobj`` driver uses) over ``fd``, whose
    changes reach the disk only at :meth:`commit`, all or (on a refused write) none."""

    def __init__(self, fd: int):
        self.fd = fd
        self.size = os.fstat(fd).st_size  # on disk, as of the last commit
        self.end = self.size  # as HDF5 sees it
        self.pos = 0
        self.dirty: dict[int, bytearray] = {}  # page index -> page

    # ---------------------------------------------------------------- file protocol
    def seek(self, pos: int, whence: int = 0) -> int:
        self.pos = pos + (0 if whence == 0 else self.pos if whence == 1 else self.end)
        return self.pos

    def tell(self) -> int:
        return self.pos

    def read(self, n: int = -1) -> bytes:
        n = self.end - self.pos if n < 0 else n
        out = bytearray(n)
        pos, done = self.pos, 0
        while done < n:
            i, off = divmod(pos + done, PAGE)
            k = min(PAGE - off, n - done)
            page = self.dirty.get(i)
            out[done : done + k] = (page if page is not None else self._disk_page(i))[off : off + k]
            done += k
        self.pos += n
        return bytes(out)

    def readinto(self, buf) -> int:
        data = self.read(len(buf))
        buf[: len(data)] = data
        return len(data)

    def write(self, data) -> int:
        data = memoryview(data).cast("B")
        n, pos, done = len(data), self.pos, 0
        while done < n:
            i, off = divmod(pos + done, PAGE)
            k = min(PAGE - off, n - done)
            page = self.dirty.get(i)
            if page is None:
                page = self.dirty[i] = self._disk_page(i)
            page[off : off + k] = data[done : done + k]
            done += k
        self.pos += n
        self.end = max(self.end, self.pos)
        return n

    def truncate(self, size: int | None = None) -> int:
        self.end = self.pos if size is None else size
        last = (self.end + PAGE - 1) // PAGE
        for i in [i for i in self.dirty if i >= last]:
            del self.dirty[i]
        return self.end

    def flush(self) -> None:
        """Nothing: the disk changes only at :meth:`commit`."""

    # ---------------------------------------------------------------- commit
    @property
    def pending(self) -> int:
        """Bytes held in memory until the next commit."""
        return PAGE * len(self.dirty)

    def commit(self, sync: bool = True) -> None:
        """Write the changes: first past the old end (then ``fdatasync`` when ``sync``), then
        inside it. On a refused write past the old end the file is truncated back to it (the
        previous commit) and the OSError is raised; the changes stay pending."""
        old, new = self.size, self.end
        try:
            if new > old:
                self._write_range(old, new)
                if sync:
                    os.fdatasync(self.fd)
        except OSError:
            try:
                os.ftruncate(self.fd, old)
            except OSError:
                pass
            raise
        self._write_range(0, min(old, new), only_dirty=True)
        if new < old:
            os.ftruncate(self.fd, new)
        self.size = new
        self.dirty.clear()

    def _write_range(self, start: int, stop: int, only_dirty: bool = False) -> None:
        """Write bytes [start, stop) from the pages (zeros where none past the old end)."""
        if start >= stop:
            return
        pages = sorted(self.dirty) if only_dirty else range(start // PAGE, (stop - 1) // PAGE + 1)
        zeros = bytes(PAGE)
        for i in pages:
            a, b = max(start, i * PAGE), min(stop, (i + 1) * PAGE)
            if a >= b:
                continue
            page = self.dirty.get(i, zeros)
            _pwrite_all(self.fd, memoryview(page)[a - i * PAGE : b - i * PAGE], a)

    def _disk_page(self, i: int) -> bytearray:
        """Page ``i`` as of the last commit (zeros past the end on disk)."""
        page = bytearray(PAGE)
        if i * PAGE < self.size:
            data = os.pread(self.fd, PAGE, i * PAGE)
            page[: len(data)] = data
        return page


def _pwrite_all(fd: int, data: memoryview, offset: int) -> None:
    while len(data):
        n = os.pwrite(fd, data, offset)
        data, offset = data[n:], offset + n


class RecordFile:
    """An open flight record being written: create it, append frames, commit, close.

    Args:
        path: the file (created or truncated).
        attrs: the daemon's attributes: str, int and float values as they are, any other value
            as JSON text in ``KEY.json``.
    """

    def __init__(self, path: str, attrs: dict, sync: bool = True):
        self.fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        self.file = CommitFile(self.fd)
        self.sync = sync
        self.appended = self.written = 0  # rows appended, rows in the file on disk
        self.h5 = h5py.File(self.file, "w")  # default (oldest) format: no open-for-write flag
        a = self.h5.attrs
        a["format"], a["schema_version"], a["complete"] = FORMAT, SCHEMA_VERSION, False
        for key, value in attrs.items():
            if key in RESERVED_ATTRS or key.endswith(".json") or "/" in key or not key:
                continue
            if isinstance(value, str | int | float) and not isinstance(value, bool):
                a[key] = value
            else:
                a[key + ".json"] = json.dumps(value, default=str)
        for s in STREAMS:
            obj = self.h5.create_group(s.name) if not s.width else self._table(s.name, s.width)
            if s.name == "raw":
                self._column(obj, "t_recv", "f8")
                self._column(obj, "payload", h5py.vlen_dtype(np.dtype("uint8")))
            elif s.name == "events":
                self._column(obj, "t", "f8")
                self._column(obj, "kind", h5py.string_dtype())
                self._column(obj, "detail", h5py.string_dtype())
            obj.attrs["columns"], obj.attrs["units"], obj.attrs["doc"] = s.columns, s.units, s.doc
        self.commit()

    def _table(self, name: str, width: int) -> h5py.Dataset:
        rows = max(16, CHUNK_BYTES // (8 * width))
        return self.h5.create_dataset(
            name, shape=(0, width), maxshape=(None, width), chunks=(rows, width), dtype="f8"
        )

    @staticmethod
    def _column(group: h5py.Group, name: str, dtype) -> None:
        group.create_dataset(
            name, shape=(0,), maxshape=(None,), chunks=(VARLEN_CHUNK,), dtype=dtype
        )

    def append(self, sid: int, rows: int, body: bytes) -> None:
        """Append the rows of one frame of stream ``sid`` (in memory until the next commit)."""
        s = STREAMS[sid]
        if s.width:
            _extend(self.h5[s.name], decode_table(body, rows, s.width))
        else:
            t, fields = decode_varlen(body, rows, FIELDS[s.name])
            g = self.h5[s.name]
            if s.name == "raw":
                _extend(g["t_recv"], t)
                pay = np.empty(rows, dtype=object)
                for i, p in enumerate(fields[0]):  # one by one: equal lengths must stay 1-D
                    pay[i] = np.frombuffer(p, dtype=np.uint8)
                _extend(g["payload"], pay, direct=True)
            else:
                _extend(g["t"], t)
                _extend(g["kind"], [k.decode("utf-8", "replace") for k in fields[0]])
                _extend(g["detail"], [d.decode("utf-8", "replace") for d in fields[1]])
        self.appended += rows

    @property
    def pending(self) -> int:
        """Bytes waiting for the next commit."""
        return self.file.pending

    def commit(self) -> None:
        """Flush HDF5 into the commit file and commit it (raises OSError: see CommitFile)."""
        self.h5.flush()
        self.file.commit(self.sync)
        self.written = self.appended

    def close(self) -> None:
        """Mark the record complete, close HDF5 and commit the last changes."""
        self.h5.attrs["complete"] = True
        self.h5.close()
        self.file.commit(self.sync)
        self.written = self.appended
        os.close(self.fd)


def _extend(ds: h5py.Dataset, rows, direct: bool = False) -> None:
    """Append ``rows`` along axis 0 (``direct``: an object array of byte arrays, which
    slice assignment would turn 2-D when they have equal lengths)."""
    n, k = ds.shape[0], len(rows)
    if k:
        ds.resize(n + k, axis=0)
        if direct:
            ds.write_direct(rows, dest_sel=np.s_[n : n + k])
        else:
            ds[n : n + k] = rows
