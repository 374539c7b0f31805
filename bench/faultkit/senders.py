"""Other UDP traffic at the daemon's EGM port: malformed datagrams and a second sender.

Every sender here talks to loopback only and counts the replies its own socket receives (the
daemon may answer its peer, the first controller, and nobody else).
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Iterator

import numpy as np

from bench.faultkit.egm_pb import EgmRobot, robot_message

_TIMESPEC = struct.Struct("@qq")
SCM_TIMESTAMPNS = 35  # = SO_TIMESTAMPNS on Linux


def recv_stamped(sock: socket.socket) -> Iterator[tuple[bytes, float]]:
    """Drain a non-blocking socket: ``(payload, kernel arrival time [s, wall clock])`` each.

    The arrival time is the kernel's stamp when the socket has ``SO_TIMESTAMPNS`` set, else now.
    """
    while True:
        try:
            data, anc, _, _ = sock.recvmsg(65535, 64)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # e.g. ICMP port unreachable reported on a connected path
            continue
        t = time.time()
        for level, kind, raw in anc:
            if level == socket.SOL_SOCKET and kind == SCM_TIMESTAMPNS and len(raw) >= 16:
                sec, nsec = _TIMESPEC.unpack_from(raw)
                t = sec + 1e-9 * nsec
        yield data, t


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _no_header(valid: bytes) -> bytes:
    m = EgmRobot()
    m.ParseFromString(valid)
    m.ClearField("header")
    return m.SerializeToString()


def _no_feedback(valid: bytes) -> bytes:
    m = EgmRobot()
    m.ParseFromString(valid)
    m.ClearField("feedBack")
    return m.SerializeToString()


def _joints(valid: bytes, values) -> bytes:
    m = EgmRobot()
    m.ParseFromString(valid)
    del m.feedBack.joints.joints[:]
    m.feedBack.joints.joints.extend(values)
    return m.SerializeToString()


def _nested(depth: int) -> bytes:
    body = b""
    for _ in range(depth):  # field 1, length-delimited, inside itself
        body = b"\x0a" + _varint(len(body)) + body
    return body


def _varint(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


# name -> f(rng, a valid EgmRobot) -> a datagram no EGM sensor may use
MALFORMED_KINDS = {
    "random_bytes": lambda r, v: r.bytes(int(r.integers(1, 200))),
    "empty": lambda r, v: b"",
    "one_byte": lambda r, v: bytes([int(r.integers(256))]),
    "truncated_in_feedback": lambda r, v: v[: int(r.integers(20, 60))],
    "bad_trailing_tag": lambda r, v: v + b"\xff" * 10 + b"\x01",
    "length_past_end": lambda r, v: b"\x0a\xff\xff\xff\x0f" + v[:8],
    "wrong_wire_type": lambda r, v: b"\x0b\x01" + v,
    "no_header": lambda r, v: _no_header(v),
    "no_feedback": lambda r, v: _no_feedback(v),
    "five_joints": lambda r, v: _joints(v, [0.0] * 5),
    "seven_joints": lambda r, v: _joints(v, [0.0] * 7),
    "nan_joint": lambda r, v: _joints(v, [0.0, float("nan"), 0.0, 0.0, 0.0, 0.0]),
    "inf_joint": lambda r, v: _joints(v, [float("inf"), 0.0, 0.0, 0.0, 0.0, 0.0]),
    "huge_joint": lambda r, v: _joints(v, [1e300, 0.0, 0.0, 0.0, 0.0, 0.0]),
    "nested_200": lambda r, v: _nested(200),
    "junk_60k": lambda r, v: r.bytes(60_000),
    "ascii": lambda r, v: b"EgmRobot seqno=1 tm=4 joints=0,0,0,0,0,0",
    "json": lambda r, v: b'{"header": {"seqno": 1}, "feedBack": {"joints": [0, 0, 0, 0, 0, 0]}}',
}


def malformed_datagram(rng: np.random.Generator, valid: bytes) -> bytes:
    """One malformed datagram of a random kind of :data:`MALFORMED_KINDS`."""
    names = list(MALFORMED_KINDS)
    return MALFORMED_KINDS[names[int(rng.integers(len(names)))]](rng, valid)


class SecondSender:
    """Another socket sending valid ``EgmRobot`` messages at 250 Hz to the daemon (a thread).

    Args:
        target: the daemon's EGM ``(host, port)`` (loopback).
        q: the joints it reports [rad] (6,): another arm's, never the peer's.
        rate_hz: messages per second.
    """

    def __init__(self, target, q, rate_hz: float = 250.0):
        if not str(target[0]).startswith("127."):
            raise ValueError(f"loopback only, not {target[0]}")
        self.target, self.q, self.period = tuple(target), np.asarray(q, float), 1.0 / rate_hz
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.sent = self.replies = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="second-sender", daemon=True)

    def start(self) -> SecondSender:
        self._thread.start()
        return self

    def stop(self) -> dict:
        """Stop, read the last replies, close; returns ``{"sent", "replies"}``."""
        self._stop.set()
        self._thread.join(2.0)
        time.sleep(0.05)
        self.replies += sum(1 for _ in recv_stamped(self.sock))
        self.sock.close()
        return {"sent": self.sent, "replies": self.replies}

    def _run(self) -> None:
        t0 = time.perf_counter()
        tm0 = 777_000
        while not self._stop.is_set():
            self.sent += 1
            msg = robot_message(self.sent, tm0 + 4 * self.sent, self.q, unix_time=time.time())
            try:
                self.sock.sendto(msg, self.target)
            except OSError:
                pass
            self.replies += sum(1 for _ in recv_stamped(self.sock))
            wait = t0 + self.sent * self.period - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
