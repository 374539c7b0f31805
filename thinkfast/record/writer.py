"""The recorder's writer process: ``python -m thinkfast.record.writer PATH``.

Started by :class:`~thinkfast.record.recorder.Recorder`; reads frames
(:mod:`~thinkfast.record.wire`) on stdin, appends them to PATH
(:class:`~thinkfast.record.file.RecordFile`) and commits every ``COMMIT_PERIOD`` or
``COMMIT_BYTES``. It polls its input (every POLL when empty) rather than waiting in ``read``:
a write into a pipe with a reader waiting wakes that reader, which costs the writing thread tens
of microseconds to milliseconds on a virtual machine, and that thread is the daemon's EGM loop.
At end of input it closes the file (complete) and
exits 0. It answers on stdout with JSON lines: ``{"ready": true}`` once the file exists,
``{"written": N}`` after each commit (dropped when the pipe is full),
``{"closed": true, "written": N}`` at the end, or ``{"failed": MESSAGE, "written": N}`` when a
write was refused, then exits 3 without touching the file again (it holds the last commit).

It runs apart from the daemon so that nothing HDF5 does (or a native crash in it) can stop EGM
replies; it ignores SIGINT and SIGTERM (the daemon closes its input when it stops) and runs at a
lower priority (nice 10).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time

POLL = 0.05  # s between reads of an empty input
COMMIT_PERIOD = 0.5  # s between commits while rows come
COMMIT_BYTES = 4 << 20  # commit earlier when this much is pending
EXIT_FAILED, EXIT_START = 3, 2


def say(out: int, msg: dict, patience: float = 0.0) -> bool:
    """Write one JSON line to the non-blocking ``out``; retry up to ``patience`` seconds."""
    line = (json.dumps(msg) + "\n").encode()
    deadline = time.monotonic() + patience
    while True:
        try:
            return os.write(out, line) == len(line)
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        except OSError:
            return False


def serve(path: str, inp: int = 0, out: int = 1) -> int:
    """Write the record at ``path`` from the frames on ``inp``; returns the exit status."""
    from thinkfast.record.file import RecordFile
    from thinkfast.record.wire import OPEN_ID, FrameSplitter, read_frame

    os.set_blocking(out, False)
    first = read_frame(inp)
    if first is None or first[0] != OPEN_ID:
        say(out, {"error": "no opening frame"}, 1.0)
        return EXIT_START
    try:
        rec = RecordFile(path, json.loads(first[2]))
    except Exception as exc:  # noqa: BLE001 - reported to the daemon, which raises it
        say(out, {"error": _message(exc)}, 1.0)
        return EXIT_START
    say(out, {"ready": True}, 1.0)
    os.set_blocking(inp, False)
    frames = FrameSplitter()
    last_commit = time.monotonic()
    try:
        while True:
            try:
                chunk = os.read(inp, 1 << 20)
            except BlockingIOError:
                chunk = None
            if chunk == b"":
                break
            for sid, rows, body in frames.feed(chunk or b""):
                if sid != OPEN_ID:
                    rec.append(sid, rows, body)
            now = time.monotonic()
            if rec.appended > rec.written and (
                now - last_commit >= COMMIT_PERIOD or rec.pending >= COMMIT_BYTES
            ):
                rec.commit()
                last_commit = now
                say(out, {"written": rec.written})  # dropped if the daemon is not reading
            if chunk is None:  # a timer, never the daemon's writes, wakes this process
                time.sleep(POLL)
        rec.close()
    except Exception as exc:  # noqa: BLE001 - the file holds the last commit; say why, stop
        say(out, {"failed": _message(exc), "written": rec.written}, 1.0)
        return EXIT_FAILED
    say(out, {"closed": True, "written": rec.written}, 1.0)
    return 0


def _message(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0] if lines else ''}".rstrip(": ")


def main() -> None:
    """Entry point of the writer process (never returns: ``os._exit`` skips HDF5's atexit)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    try:
        os.nice(10)
    except OSError:
        pass
    code = EXIT_START
    try:
        code = serve(sys.argv[1])
    finally:
        os._exit(code)


if __name__ == "__main__":
    main()
