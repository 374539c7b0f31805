"""The recorder's end of its writer process: start it, send frames without ever blocking, read
its news, and finish it within a deadline (see :mod:`~thinkfast.record.writer`)."""

from __future__ import annotations

import fcntl
import json
import logging
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from thinkfast.errors import RecorderError

WRITER = "thinkfast.record.writer"
log = logging.getLogger("thinkfast.run")
_early: dict[str, tuple[subprocess.Popen, object]] = {}  # started ahead, by absolute path


def _spawn(path: Path) -> tuple[subprocess.Popen, object]:
    """A writer process for ``path`` and its stderr file; it imports, then waits for the
    opening frame on stdin before it creates anything."""
    err = tempfile.TemporaryFile()  # the writer's stderr: read only if it dies early
    proc = subprocess.Popen(
        [sys.executable, "-m", WRITER, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=err,
        bufsize=0,
    )
    return proc, err


def start_writer_early(path: Path) -> None:
    """Start the writer process for ``path`` now; the :class:`WriterPipe` for the same path
    takes it. Its imports (NumPy, h5py) then run beside the caller's own start-up instead of
    after it. Until the opening frame comes it touches no file; a writer never taken ends when
    this process does (end of its input). This module imports no NumPy or h5py itself, so the
    daemon calls it first thing."""
    _early[os.path.abspath(path)] = _spawn(path)


class WriterGone(Exception):
    """The writer process is no longer reading (it failed, exited or was killed)."""


class WriterPipe:
    """A started writer process for ``path``, ready (its file exists).

    Args:
        path: the record file.
        attrs: the file's attributes (opening frame).
        pipe_bytes: capacity to ask for the frame pipe (Linux; the default 64 KiB otherwise).
        timeout: seconds to wait for the writer to be ready.

    Raises:
        RecorderError: the writer could not create the file or did not start in time.
    """

    def __init__(self, path: Path, attrs: dict, pipe_bytes: int, timeout: float):
        from thinkfast.record.wire import open_frame  # NumPy: not for start_writer_early

        self.path = path
        self.proc, self.err = _early.pop(os.path.abspath(path), None) or _spawn(path)
        self.fd = self.proc.stdin.fileno()
        self.capacity = _set_pipe_size(self.fd, pipe_bytes)
        _set_pipe_size(self.proc.stdout.fileno(), pipe_bytes)
        self.tail = memoryview(b"")  # the unsent end of a frame already started
        self.buf = b""
        self.last: dict = {}  # the writer's last message
        try:
            first = memoryview(open_frame(attrs))
            while first:
                first = first[os.write(self.fd, first) :]
            os.set_blocking(self.fd, False)
            os.set_blocking(self.proc.stdout.fileno(), False)
            deadline = time.monotonic() + timeout
            while not self.last and time.monotonic() < deadline and self.proc.poll() is None:
                select.select([self.proc.stdout], [], [], 0.05)
                self.read()
        except OSError:
            pass
        if not self.last.get("ready"):
            late = self.proc.poll() is None  # still starting: killed here, not by itself
            self.kill()
            why = self.last.get("error") or (
                f"writer not ready within {timeout:g} s" if late else self.death("writer exited")
            )
            raise RecorderError(f"{path}: cannot record here: {why}")

    def send(self, frames: list[tuple[bytes, memoryview]]) -> int:
        """Put frames (header, body) into the pipe with one system call, as many as fit now.
        Returns how many were taken (the end of the last one may wait in ``tail``); 0 while
        ``tail`` cannot be sent. Raises WriterGone."""
        if self.tail and not self.send_tail():
            return 0
        n = self._write([x for f in frames for x in f])
        taken = 0
        for head, body in frames:
            if n is None or n <= 0:
                break
            size = len(head) + body.nbytes
            if n < size:
                self.tail = memoryview(b"".join((head, body))[n:])
            n -= size
            taken += 1
        return taken

    def send_tail(self) -> bool:
        """Send what is left of a started frame; True when nothing is left."""
        n = self._write([self.tail])
        if n is not None:
            self.tail = self.tail[n:]
        return not self.tail

    def _write(self, buffers: list) -> int | None:
        try:
            return os.writev(self.fd, buffers)
        except BlockingIOError:
            return None
        except OSError as exc:  # EPIPE: the writer exited
            raise WriterGone(self.death(f"writer gone ({exc.strerror})")) from None

    def wait_writable(self, timeout: float) -> None:
        select.select([], [self.fd], [], timeout)

    def read(self) -> list[dict]:
        """The writer's new messages (never blocks); ``last`` is the newest."""
        try:
            while chunk := os.read(self.proc.stdout.fileno(), 65536):
                self.buf += chunk
        except (BlockingIOError, ValueError):
            pass
        except OSError:
            return []
        *lines, self.buf = self.buf.split(b"\n")
        msgs = []
        for line in lines:
            try:
                msgs.append(json.loads(line))
            except ValueError:
                continue
        if msgs:
            self.last = msgs[-1]
        return msgs

    def finish(self, deadline: float) -> dict:
        """Close the frame pipe (end of input), wait for the writer until ``deadline``
        (monotonic), kill it after that. Returns its last message (``closed``, ``failed``) or
        ``{"failed": why}``."""
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        final: dict | None = None
        while True:
            for m in self.read():
                if "closed" in m or "failed" in m:
                    final = m
            if self.proc.poll() is not None:
                for m in self.read():
                    if "closed" in m or "failed" in m:
                        final = m
                break
            left = deadline - time.monotonic()
            if left <= 0:
                self.kill()
                return {"failed": "writer did not finish in time: killed (the file holds its "
                        "last commit)"}  # fmt: skip
            select.select([self.proc.stdout], [], [], min(left, 0.05))
        self.err.close()
        return final or {"failed": self.death("writer ended without closing the file")}

    def kill(self) -> None:
        """Kill the writer and reap it (its file keeps the last commit)."""
        try:
            self.proc.kill()
            self.proc.wait(1.0)
        except (OSError, subprocess.TimeoutExpired):
            pass
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except OSError:
                pass

    def death(self, fallback: str) -> str:
        """Why the writer died: its exit status and last stderr line, or ``fallback``."""
        code = self.proc.poll()
        if code is None:
            return fallback
        try:
            self.err.seek(0)
            lines = self.err.read().decode("utf-8", "replace").strip().splitlines()
        except (OSError, ValueError):
            lines = []
        how = f"signal {-code}" if code < 0 else f"status {code}"
        return f"writer exited ({how}){': ' + lines[-1] if lines else ''}"


def _set_pipe_size(fd: int, size: int) -> int:
    """Ask for a pipe capacity of ``size`` bytes; returns the capacity it has."""
    try:
        return fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, size)
    except (OSError, AttributeError):
        try:
            return fcntl.fcntl(fd, fcntl.F_GETPIPE_SZ)
        except (OSError, AttributeError):
            return 65536


def check_target(path: Path) -> None:
    """Raise :class:`RecorderError` unless ``path`` can be created (or replaced) as a file."""

    def refuse(reason: str):
        raise RecorderError(f"{path}: cannot record here: {reason}")

    if path.is_dir():
        refuse("it is a directory")
    parent = path.parent
    if not parent.exists():
        refuse(f"directory {parent} does not exist")
    if not parent.is_dir():
        refuse(f"{parent} is not a directory")
    if not os.access(parent, os.W_OK):
        refuse(f"directory {parent} is not writable")
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644))
    except OSError as exc:
        refuse(f"cannot create the file ({exc.strerror or exc})")
    try:
        free = os.statvfs(parent).f_bavail * os.statvfs(parent).f_frsize
    except OSError:
        return
    if free < 100 << 20:
        log.warning("flight record %s: only %.0f MB free on its disk", path, free / 1e6)
