"""A toy controller link: an in-memory controller that speaks JSON, not EGM.

:class:`ToyController` is a perfect servo on its own 4 ms clock: each cycle it sends
``{"clock_ms", "cycle", "joints", "enabled"}`` and takes the next reply's joints as where the
arm is. :class:`ToyLink` is the daemon's side of the same socket pair, a
:class:`thinkfast.control.link.ControllerLink` in a few lines: it turns the message into the
core's :class:`~thinkfast.control.link.Feedback` and sends ``{"joints", "speeds"}`` back. Its
one registration is ``thinkfast.link.registry.register("toy", ...)`` (tests/test_toy_link.py).
"""

from __future__ import annotations

import json
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np

from thinkfast.control.link import Feedback


@dataclass
class ToyCounters:
    """What the status's ``egm`` object shows for this link."""

    received: int = 0
    replied: int = 0
    behind: int = 0


class ToyLink:
    """The daemon's end of the toy controller's socket pair (module doc)."""

    def __init__(self, sock: socket.socket, reply):
        self._sock, self._reply = sock, reply
        self._sock.setblocking(False)
        self.address = "memory"
        self.peer: tuple[str, int] | None = None
        self.behind = False
        self.counters = ToyCounters()
        self.foreign_sources: dict = {}
        self.timing = None

    def fileno(self) -> int:
        return self._sock.fileno()

    def poll(self) -> int:
        newest = None
        while True:
            try:
                newest = self._sock.recv(65536)
            except BlockingIOError:
                break
            self.counters.received += 1
        if newest is None:
            return 0
        msg = json.loads(newest)
        self.peer = ("toy", 1)
        fb = Feedback(
            msg["clock_ms"], np.array(msg["joints"]), msg["cycle"], msg["enabled"],
            (("enabled", msg["enabled"]),),
        )  # fmt: skip
        answer = self._reply(fb, None)
        if answer is None:
            return 0
        q, qd = answer[0], answer[1]
        self._sock.send(
            json.dumps({"joints": list(map(float, q)), "speeds": list(map(float, qd))}).encode()
        )
        self.counters.replied += 1
        return 1

    def close(self) -> None:
        self._sock.close()


class ToyController(threading.Thread):
    """A perfect servo at ``dt`` [s]: the arm is where the last reply put it (module doc).

    Attributes:
        history: ``(wall time [s], joints [rad] (6,))`` of every cycle.
    """

    def __init__(self, sock: socket.socket, q0, dt: float = 0.004):
        super().__init__(daemon=True)
        self._sock, self.q, self.dt = sock, np.array(q0, dtype=float), dt
        self._sock.settimeout(dt)
        self.history: list[tuple[float, np.ndarray]] = []
        self.replies = 0
        self.stop = threading.Event()

    def run(self) -> None:
        t0, k = time.monotonic(), 0
        while not self.stop.is_set():
            msg = {"clock_ms": 4 * k, "cycle": k, "joints": self.q.tolist(), "enabled": True}
            try:
                self._sock.send(json.dumps(msg).encode())
            except OSError:  # the daemon closed its end: it has stopped
                return
            self.history.append((time.time(), self.q.copy()))
            try:
                reply = json.loads(self._sock.recv(65536))
                self.q = np.array(reply["joints"])
                self.replies += 1
            except (TimeoutError, BlockingIOError):
                pass  # no answer this cycle: the arm holds
            k += 1
            time.sleep(max(0.0, t0 + k * self.dt - time.monotonic()))


def toy_pair(q0) -> tuple[ToyController, callable]:
    """A toy controller and the link factory the registry is given for it."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    controller = ToyController(theirs, q0)
    return controller, lambda spec, reply: ToyLink(ours, reply)
