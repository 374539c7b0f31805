"""The fault controller in a process of its own, driven through a pipe.

A controller thread that shares its interpreter with zenoh callbacks, publishers and the checker
waits for the GIL and misses its 4 ms cycles; a real controller does not. :class:`RemoteController`
runs a :class:`~bench.faultkit.controller.FaultController` in a child process (a fresh
interpreter: ``python -m bench.faultkit.remote``; nothing of the parent's zenoh threads is
inherited) and offers the same controls; every call is one round trip of pickled frames on the
child's stdin/stdout (about 0.1 ms).
"""

from __future__ import annotations

import pickle
import struct
import subprocess
import sys
import threading

import numpy as np

from bench.faultkit import spawn
from bench.faultkit.controller import FaultController

_SETTABLE = ("duplicate", "malformed")
_READABLE = ("last_cmd", "malformed_sent", "gap_log", "address", "realtime")
_CALLS = ("gap", "random_pauses", "freeze", "absurd", "reset_seqno", "history", "jitter")


class _Conn:
    """Length-prefixed pickles over a pair of binary streams."""

    _LEN = struct.Struct("<Q")

    def __init__(self, rfile, wfile):
        self.r, self.w = rfile, wfile

    def send(self, obj) -> None:
        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        self.w.write(self._LEN.pack(len(data)) + data)
        self.w.flush()

    def recv(self):
        head = self.r.read(self._LEN.size)
        if len(head) < self._LEN.size:
            raise EOFError
        return pickle.loads(self.r.read(self._LEN.unpack(head)[0]))


def _serve(conn: _Conn) -> None:
    sys.setswitchinterval(0.0005)  # the controller thread gets the GIL back quickly
    ctl = FaultController(*conn.recv()).start()
    conn.send(ctl.address)
    while True:
        try:
            name, a = conn.recv()
        except EOFError:
            name = "stop"
        if name == "stop":
            ctl.stop()
            try:
                conn.send(ctl.rows.take())
            except OSError:  # the parent is gone
                pass
            return
        try:
            if name == "take":
                out = ctl.rows.take()
            elif name == "total":
                out = ctl.rows.total
            elif name == "set":
                if a[0] in _SETTABLE:
                    setattr(ctl, a[0], a[1])
                out = None
            elif name == "get":
                out = getattr(ctl, a[0]) if a[0] in _READABLE else None
            elif name in _CALLS:
                out = getattr(ctl, name)(*a)
            else:
                out = ValueError(f"unknown call {name}")
        except Exception as exc:  # report to the caller, keep serving
            out = exc
        conn.send(out)


class _Rows:
    """``rows.take()`` / ``rows.total`` of the remote controller."""

    def __init__(self, owner: RemoteController):
        self._owner = owner
        self._final: np.ndarray | None = None

    def take(self) -> np.ndarray:
        if self._final is not None:
            out, self._final = self._final, np.zeros((0, self._final.shape[1]))
            return out
        return self._owner._call("take")

    @property
    def total(self) -> int:
        return self._owner._call("total")


class RemoteController:
    """Same arguments and controls as :class:`FaultController`, in a child process."""

    def __init__(self, target, servo, q0=None, seed=0, history_s=120.0, q_limits=None,
                 fifo=None):  # fmt: skip
        self._args = (tuple(target), servo, None if q0 is None else np.asarray(q0, float), seed,
                      history_s, q_limits, fifo)  # fmt: skip
        self._lock = threading.Lock()
        self.rows = _Rows(self)
        self._stopped = False
        self.address = None
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 60.0) -> RemoteController:
        self.proc = spawn("remote", stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self._conn = _Conn(self.proc.stdout, self.proc.stdin)
        self._conn.send(self._args)
        try:
            self.address = self._conn.recv()
        except EOFError:
            raise RuntimeError("the fault controller process did not start") from None
        return self

    def _call(self, name: str, *args):
        with self._lock:
            if self._stopped:
                raise RuntimeError("the fault controller has stopped")
            self._conn.send((name, args))
            out = self._conn.recv()
        if isinstance(out, Exception):
            raise out
        return out

    def __getattr__(self, name):
        if name in _READABLE:
            return self._call("get", name)
        if name in _CALLS:
            return lambda *a: self._call(name, *a)
        raise AttributeError(name)

    def __setattr__(self, name, value):
        if name in _SETTABLE:
            self._call("set", name, value)
        else:
            object.__setattr__(self, name, value)

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the controller; the rows not taken yet stay readable through ``rows.take()``."""
        with self._lock:
            if self._stopped or self.proc is None:
                return
            self._stopped = True
            try:
                self._conn.send(("stop", ()))
                self.rows._final = self._conn.recv()
            except (OSError, EOFError, ValueError):
                pass
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()


if __name__ == "__main__":
    _serve(_Conn(sys.stdin.buffer, sys.stdout.buffer))
