"""EGM sensor endpoint: one UDP socket, one ``EgmSensor`` reply per valid ``EgmRobot``.

The ABB controller is the UDP client: every 4 ms it sends an ``EgmRobot`` to this socket and the
sensor answers to the address and port the packet came from. :class:`EgmServer` owns the socket
and the protocol bookkeeping only; *what* to answer comes from ``reply_fn`` (in the daemon, the
safety supervisor's output). Two ways to drive it:

* from a fixed-rate loop: call :meth:`EgmServer.poll` each tick (never blocks);
* from a dedicated thread: :meth:`EgmServer.serve` waits on the socket and replies as each
  packet arrives (lowest latency: the reply leaves within one ``poll`` of the arrival).

``poll`` never raises for anything that arrives on the wire: foreign senders, malformed packets,
failing ``reply_fn`` calls and socket errors are dropped and counted in :class:`EgmCounters`.
With ``timing=True`` it also keeps :class:`ReplyTimes`: how long each request waited in the
socket (from the kernel's arrival time stamp) and how long the reply took to leave.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import math
import select
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from thinkfast.errors import ThinkfastError
from thinkfast.runtime.egm_proto import (
    MSGTYPE_CORRECTION,
    UINT32,
    EgmDecodeError,
    RobotFeedback,
    decode_robot,
    encode_sensor,
)
from thinkfast.runtime.reply_times import ReplyTimes

ReplyFn = Callable[[RobotFeedback], "tuple[np.ndarray, np.ndarray]"]
MAX_DATAGRAM = 65535
SO_TIMESTAMPNS = 35  # Linux <asm-generic/socket.h> (also SCM_TIMESTAMPNS); Python lacks the name
_TIMESPEC = struct.Struct("@qq")  # struct timespec on 64-bit Linux: seconds, nanoseconds


class EgmAddressError(ThinkfastError):
    """A ``HOST:PORT`` or controller IP string is unusable; the message shows the expected form."""


@dataclasses.dataclass
class EgmCounters:
    """What the server saw, cumulative since it was created.

    Attributes:
        received: datagrams read from the socket (all senders).
        replied: ``EgmSensor`` messages sent.
        foreign: datagrams dropped because the sender is not ``controller_ip``.
        malformed: datagrams dropped because they are not a usable ``EgmRobot``.
        reply_errors: valid requests left unanswered because ``reply_fn`` raised or returned an
            unencodable setpoint (wrong shape, non-finite).
        socket_errors: ``recvfrom``/``sendto`` failures (the datagram is lost).
    """

    received: int = 0
    replied: int = 0
    foreign: int = 0
    malformed: int = 0
    reply_errors: int = 0
    socket_errors: int = 0


def parse_hostport(text: str, what: str = "--egm-bind") -> tuple[str, int]:
    """``"HOST:PORT"`` (or ``"[IPv6]:PORT"``) -> ``(host, port)``.

    Args:
        text: the address string; port 0 asks the OS for a free port.
        what: name of the option, for the error message.

    Raises:
        EgmAddressError: no colon, empty host, or a port that is not an integer in 0..65535.
    """
    text = str(text).strip()
    host, sep, port_s = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not host or not port_s.isdigit() or not 0 <= int(port_s) <= 65535:
        raise EgmAddressError(
            f"{what}: {text!r} is not HOST:PORT (e.g. 0.0.0.0:6510, 127.0.0.1:6511, [::1]:6510)"
        )
    return host, int(port_s)


def _check_ip(ip: str | None) -> str | None:
    if ip is None:
        return None
    try:
        return str(ipaddress.ip_address(ip.strip()))
    except ValueError:
        raise EgmAddressError(
            f"--egm-controller: {ip!r} is not an IP address (e.g. 192.168.125.1)"
        ) from None


class EgmServer:
    """Non-blocking UDP EGM sensor endpoint.

    Args:
        bind: ``"HOST:PORT"`` string or ``(host, port)`` to bind; port 0 picks a free port.
        reply_fn: ``reply_fn(feedback) -> (q_rad, qd_rad_s)``, two sequences of 6 finite values:
            the setpoint to send in answer to ``feedback``. Called once per valid request, in
            arrival order, on the thread that calls :meth:`poll`.
        controller_ip: when set, only datagrams from this IP are served; others are counted in
            ``counters.foreign`` and dropped.
        clock: monotonic clock [s] for the ``tm`` field (milliseconds since the server started)
            and for :attr:`last_rx_time`.
        rcvbuf_bytes: requested kernel receive buffer size [bytes].
        timing: keep :attr:`timing` (reply times; kernel arrival stamps where the OS has them).

    Attributes:
        counters: :class:`EgmCounters`.
        seqno: sequence number of the last ``EgmSensor`` sent (0 before the first).
        last_feedback: the last valid :class:`RobotFeedback`, or None.
        last_rx_time: ``clock()`` when it arrived [s] (for loss-of-traffic checks), or None.
        timing: :class:`ReplyTimes`, or None without ``timing``.

    Raises:
        EgmAddressError: bad address strings, or the socket cannot be bound (message says why).
    """

    def __init__(
        self,
        bind: str | tuple[str, int],
        reply_fn: ReplyFn,
        controller_ip: str | None = None,
        clock: Callable[[], float] = time.perf_counter,
        rcvbuf_bytes: int = 1 << 20,
        timing: bool = False,
    ):
        host, port = parse_hostport(bind) if isinstance(bind, str) else bind
        self.controller_ip = _check_ip(controller_ip)
        self.reply_fn = reply_fn
        self.counters = EgmCounters()
        self.seqno = 0
        self.last_feedback: RobotFeedback | None = None
        self.last_rx_time: float | None = None
        self._last_exchange: tuple | None = None  # (request bytes, q, qd) for warm()
        self._clock = clock
        self._t0 = clock()
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise EgmAddressError(f"cannot bind EGM socket to {host}:{port} ({exc})") from None
        self._sock.setblocking(False)
        self.timing = ReplyTimes() if timing else None
        self._stamped = False
        if timing and sys.platform == "linux":
            try:
                self._sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self._stamped = True
            except OSError:
                pass

    @property
    def address(self) -> tuple[str, int]:
        """The bound ``(host, port)`` (the real port when bound to port 0)."""
        return self._sock.getsockname()[:2]

    def fileno(self) -> int:
        """Socket descriptor, for ``select``/``selectors`` in an outer loop."""
        return self._sock.fileno()

    def poll(self, max_packets: int = 1000) -> int:
        """Drain the socket: answer every valid ``EgmRobot``, drop and count the rest.

        Args:
            max_packets: upper bound on datagrams handled in this call (bounds the tick time).

        Returns:
            Number of replies sent.
        """
        sent = 0
        c = self.counters
        timing = self.timing
        for _ in range(max_packets):
            try:
                if self._stamped:
                    data, anc, _, addr = self._sock.recvmsg(MAX_DATAGRAM, 64)
                else:
                    data, addr = self._sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                c.socket_errors += 1
                continue
            if timing is not None:
                t_read = time.perf_counter()
                wait = arrival_age(anc) if self._stamped else math.nan
            c.received += 1
            if (
                self.controller_ip is not None
                and addr[0].removeprefix("::ffff:") != self.controller_ip
            ):
                c.foreign += 1  # (an IPv4 sender on a dual-stack socket shows as ::ffff:a.b.c.d)
                continue
            try:
                fb = decode_robot(data)
            except EgmDecodeError:
                c.malformed += 1
                continue
            self.last_feedback = fb
            self.last_rx_time = self._clock()
            try:
                q, qd = self.reply_fn(fb)
                tm = int((self.last_rx_time - self._t0) * 1000.0)
                payload = encode_sensor(
                    (self.seqno + 1) & UINT32, tm, q, qd, mtype=MSGTYPE_CORRECTION
                )
            except Exception:  # a failing setpoint source must never stop the I/O loop
                c.reply_errors += 1
                continue
            if timing is not None:
                work = time.perf_counter() - t_read
            try:
                self._sock.sendto(payload, addr)
            except OSError:
                c.socket_errors += 1
                continue
            self.seqno = (self.seqno + 1) & UINT32
            self._last_exchange = (data, q, qd)
            c.replied += 1
            sent += 1
            if timing is not None:
                timing.add(wait, work)
        return sent

    def warm(self) -> None:
        """Decode the last request and encode the last reply again, discarding both.

        Keeps the reply path's code and data in the CPU caches: on a virtual machine Python runs
        several times slower when it wakes up cold. A loop that spins before the next request is
        due calls it there. No state changes; nothing is sent.
        """
        if self._last_exchange is None:
            return
        data, q, qd = self._last_exchange
        try:
            decode_robot(data)
            encode_sensor(self.seqno, 0, q, qd, mtype=MSGTYPE_CORRECTION)
        except Exception:  # it was served once: cannot fail, but warming must never raise
            pass

    def serve(self, stop: threading.Event, wait_s: float = 0.05) -> None:
        """Reply to packets as they arrive until ``stop`` is set (body of a dedicated thread).

        Args:
            stop: set it to return; checked at least every ``wait_s``.
            wait_s: longest blocking wait on the socket [s].
        """
        poller = select.poll()  # not select.select: no FD_SETSIZE limit
        poller.register(self._sock.fileno(), select.POLLIN)
        wait_ms = max(1, int(wait_s * 1000))
        while not stop.is_set():
            if poller.poll(wait_ms):
                self.poll()

    def close(self) -> None:
        """Close the socket (idempotent)."""
        self._sock.close()

    def __enter__(self) -> EgmServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def arrival_age(ancdata) -> float:
    """Seconds since the kernel stamped the datagram (``SCM_TIMESTAMPNS``), NaN if absent."""
    for level, kind, raw in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(raw)
            return time.time() - (sec + 1e-9 * nsec)
    return math.nan
