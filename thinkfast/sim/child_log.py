"""The log of a child process the simulators start (``thinkfast-run``, ``thinkfast-detect``):
its stderr into a temporary file, read back whole when it fails."""

from __future__ import annotations

import os


def log_text(log) -> str:
    """The whole of ``log``, a file a child process writes through (its stderr), read with
    ``pread``: the child and this process share one file offset, and a ``seek(0)`` here while
    the child writes would put its next line over the start of the file."""
    fd = log.fileno()
    return os.pread(fd, os.fstat(fd).st_size, 0).decode("utf-8", "replace")
