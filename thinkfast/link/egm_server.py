"""EGM sensor endpoint: one UDP socket, one ``EgmSensor`` reply per valid ``EgmRobot``.

The ABB controller is the UDP client: every 4 ms it sends an ``EgmRobot`` to this socket and the
sensor answers to the address and port the packet came from. :class:`EgmServer` owns the socket
and the protocol bookkeeping only; *what* to answer comes from ``reply_fn`` (in the daemon, the
safety supervisor's output). Two ways to drive it:

* from a fixed-rate loop: call :meth:`EgmServer.poll` each tick (never blocks);
* from a dedicated thread: :meth:`EgmServer.serve` waits on the socket and replies as each
  packet arrives (lowest latency: the reply leaves within one ``poll`` of the arrival).

One peer: the server answers exactly one controller, the one named (``controller``: an address
and optionally a port) or else the first sender of a valid ``EgmRobot``. Another sender becomes
the peer only after the current one has been silent for ``handover`` seconds (a controller that
restarts, or moves to another port); until then its packets are counted by source and never
answered. Each :meth:`EgmServer.poll` drains what is pending (at most ``max_packets``: the work
spent on a flood is bounded), and answers only the newest valid packet of the peer: older ones
are out of date already (counted ``superseded``), and a reply is only ever computed once.

``poll`` never raises for anything that arrives on the wire: foreign senders, malformed packets,
failing ``reply_fn`` calls and socket errors are dropped and counted in :class:`EgmCounters`.
With ``timing=True`` it also keeps :class:`ReplyTimes`: how long each request waited in the
socket (from the kernel's arrival time stamp) and how long the reply took to leave.

Addresses (``--egm-bind``, ``--egm-controller``) are parsed in :mod:`thinkfast.link.egm_address`.
"""

from __future__ import annotations

import dataclasses
import math
import select
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from thinkfast.contract.egm import (
    MSGTYPE_CORRECTION,
    UINT32,
    EgmDecodeError,
    RobotFeedback,
    decode_robot,
    encode_sensor,
)
from thinkfast.link.egm_address import EgmAddressError, parse_controller, parse_hostport
from thinkfast.link.reply_times import ReplyTimes

ReplyFn = Callable[..., "tuple[np.ndarray, np.ndarray] | None"]
MAX_DATAGRAM = 65535
SO_TIMESTAMPNS = 35  # Linux <asm-generic/socket.h> (also SCM_TIMESTAMPNS); Python lacks the name
_TIMESPEC = struct.Struct("@qq")  # struct timespec on 64-bit Linux: seconds, nanoseconds
_PEEK = int(socket.MSG_PEEK | socket.MSG_DONTWAIT)  # once: combining the flags costs an enum op


@dataclasses.dataclass
class EgmCounters:
    """What the server saw, cumulative since it was created.

    Attributes:
        received: datagrams read from the socket (all senders).
        replied: ``EgmSensor`` messages sent.
        foreign: datagrams dropped because the sender is not the peer (by source in
            :attr:`EgmServer.foreign_sources`).
        malformed: datagrams of the peer (or of a would-be peer) that are not a usable
            ``EgmRobot``.
        superseded: valid packets of the peer left unanswered because a newer one was pending.
        handovers: times the peer changed (the first peer included).
        reply_errors: valid requests left unanswered because ``reply_fn`` raised or returned an
            unencodable setpoint (wrong shape, non-finite).
        deferred: valid requests left unanswered because ``reply_fn`` returned None (by
            design: after a silence the daemon waits for packets that measure the velocity).
        socket_errors: ``recvfrom``/``sendto`` failures (the datagram is lost).
        behind: requests that arrived before the reply to the one before them left (with
            ``timing`` only): that reply reached the controller a cycle late.
    """

    received: int = 0
    replied: int = 0
    foreign: int = 0
    malformed: int = 0
    superseded: int = 0
    handovers: int = 0
    reply_errors: int = 0
    deferred: int = 0
    socket_errors: int = 0
    behind: int = 0


def _source(addr) -> tuple[str, int]:
    """``(ip, port)`` of a sender; an IPv4 sender on a dual-stack socket shows as ::ffff:a.b.c.d."""
    return addr[0].removeprefix("::ffff:"), addr[1]


MAX_SOURCES = 64  # foreign senders counted by name; the rest under "other"


class EgmServer:
    """Non-blocking UDP EGM sensor endpoint.

    Args:
        bind: ``"HOST:PORT"`` string or ``(host, port)`` to bind; port 0 picks a free port.
        reply_fn: ``reply_fn(feedback, before) -> (q_rad, qd_rad_s)``, two sequences of 6 finite
            values: the setpoint to send in answer to ``feedback``; ``before`` is the peer's
            newest valid packet before it when that one was superseded in the same drain
            (malformed ones between them skipped; else None). A third element, when there is
            one, is their ``sensor_body`` encoded ahead (:mod:`thinkfast.contract.egm`).
            Returning None leaves the request unanswered (counted in ``deferred``).
            Called once per answered request, on the thread that calls :meth:`poll`.
        controller: ``"IP"`` or ``"IP:PORT"`` of the one controller to serve; None serves the
            first sender of a valid ``EgmRobot`` (see the module doc).
        handover: a silent peer [s] after which another sender may become the peer.
        clock: monotonic clock [s] for the ``tm`` field (milliseconds since the server started)
            and for :attr:`last_rx_time`.
        rcvbuf_bytes: requested kernel receive buffer size [bytes].
        timing: keep :attr:`timing` (reply times; kernel arrival stamps where the OS has them).

    Attributes:
        counters: :class:`EgmCounters`.
        seqno: sequence number of the last ``EgmSensor`` sent (0 before the first).
        peer: ``(ip, port)`` of the controller being served, None before the first.
        foreign_sources: ``{"ip:port": datagrams}`` of other senders (``"other"`` past
            :data:`MAX_SOURCES` names).
        last_rx_time: ``clock()`` when the peer's last valid packet arrived [s], or None.
        timing: :class:`ReplyTimes`, or None without ``timing``.

    Raises:
        EgmAddressError: bad address strings, or the socket cannot be bound (message says why).
    """

    def __init__(
        self,
        bind: str | tuple[str, int],
        reply_fn: ReplyFn,
        controller: str | None = None,
        clock: Callable[[], float] = time.perf_counter,
        rcvbuf_bytes: int = 1 << 20,
        timing: bool = False,
        handover: float = 1.0,
    ):
        host, port = parse_hostport(bind) if isinstance(bind, str) else bind
        self.controller = parse_controller(controller)
        self.handover = handover
        self.reply_fn = reply_fn
        self.counters = EgmCounters()
        self.seqno = 0
        self.behind = False  # the request being answered arrived before the last reply left
        self._sent_at = -math.inf  # the wall clock when the last reply left [s]
        self._pending_at_send = False  # the peer's next request was waiting as the reply left
        self.peer: tuple[str, int] | None = None
        self.foreign_sources: dict[str, int] = {}
        self.last_rx_time: float | None = None
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
        self._pending = select.poll()  # a datagram waiting? (cheaper than a read that fails)
        self._pending.register(self._sock.fileno(), select.POLLIN)
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

    def poll(self, max_packets: int = 256) -> int:
        """Drain the socket and answer the newest valid ``EgmRobot`` of the peer (module doc).

        Args:
            max_packets: upper bound on datagrams read in this call (bounds the time a flood
                can take from the loop).

        Returns:
            Number of replies sent (0 or 1).
        """
        c = self.counters
        timing = self.timing
        peer_packets: list[tuple] = []  # (data, addr, t_read, stamp, wait, source), oldest first
        for k in range(max_packets):
            if k and not self._pending.poll(0):
                break
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
            c.received += 1
            src = _source(addr)
            if not self._may_serve(src):
                self._count_foreign(src)
                continue
            t_read = time.perf_counter() if timing is not None else 0.0
            stamp = arrival_stamp(anc) if self._stamped and timing is not None else math.nan
            peer_packets.append((data, addr, t_read, stamp, time.time() - stamp, src))
        return self._answer_newest(peer_packets)

    def _may_serve(self, src: tuple[str, int]) -> bool:
        """``src`` is (or may become) the peer."""
        if self.controller is not None:
            ip, port = self.controller
            return src[0] == ip and (port is None or src[1] == port)
        if self.peer is None or src == self.peer:
            return True
        silent = self.last_rx_time is None or self._clock() - self.last_rx_time > self.handover
        return silent

    def _count_foreign(self, src: tuple[str, int]) -> None:
        self.counters.foreign += 1
        key = f"{src[0]}:{src[1]}"
        sources = self.foreign_sources
        if key not in sources and len(sources) >= MAX_SOURCES:
            key = "other"
        sources[key] = sources.get(key, 0) + 1

    def _answer_newest(self, packets: list) -> int:
        """Answer the peer's newest packet that decodes. Without a peer (or after its silence),
        the sender of the oldest valid packet becomes the peer. Count the rest: the peer's
        older packets superseded, other senders' foreign."""
        c = self.counters
        if len(packets) == 1 and packets[0][5] == self.peer:  # the usual: one, from the peer
            data, addr, t_read, stamp, wait, _ = packets[0]
            try:
                fb = decode_robot(data)
            except EgmDecodeError:
                c.malformed += 1
                return 0
            return self._reply(fb, None, addr, t_read, stamp, wait)
        sources = [p[5] for p in packets]
        peer = self.peer if self.peer in sources else None
        bad: set[int] = set()
        if peer is None:  # a handover is due (_may_serve let these in): the first valid sender
            for k, (data, *_) in enumerate(packets):
                try:
                    decode_robot(data)
                except EgmDecodeError:
                    bad.add(k)
                    c.malformed += 1
                    continue
                peer = sources[k]
                break
            if peer is None:
                return 0
            self.peer = peer
            c.handovers += 1
        answered, before, rest = -1, None, []
        for k in range(len(packets) - 1, -1, -1):
            if sources[k] != peer:
                self._count_foreign(sources[k])
            elif before is not None:
                rest.append(k)  # counted after the reply: no decoding ahead of it
            elif answered >= 0:
                before = self._older(packets[k][0], k in bad)  # the peer's valid one before
            elif k not in bad:
                try:
                    fb = decode_robot(packets[k][0])
                except EgmDecodeError:
                    c.malformed += 1
                    continue
                answered = k
                data, addr, t_read, stamp, wait, _ = packets[k]
        if answered < 0:
            return 0
        sent = self._reply(fb, before, addr, t_read, stamp, wait)
        for k in rest:
            self._older(packets[k][0], k in bad)
        return sent

    def _older(self, data: bytes, counted: bool) -> RobotFeedback | None:
        """A packet of the peer's older than the answered one: superseded when it decodes
        (returned), else malformed (unless ``counted`` so already)."""
        try:
            older = decode_robot(data)
        except EgmDecodeError:
            self.counters.malformed += not counted
            return None
        self.counters.superseded += 1
        return older

    def _reply(
        self, fb: RobotFeedback, before, addr, t_read: float, stamp: float, wait: float
    ) -> int:
        c = self.counters
        self.last_rx_time = self._clock()
        # this packet arrived before the last reply left: that reply reached the controller after
        # the cycle that sent this packet began (the controller kept its reference before). Seen
        # either way: waiting in the socket as that reply left, or stamped by the kernel before
        # (the stamp alone misses: a new socket's first packets may be stamped when read). Both
        # times on the kernel's clock (the wall clock): no other clock read in between, which a
        # preemption could stretch
        self.behind = self._pending_at_send or stamp < self._sent_at  # NaN: False
        c.behind += self.behind
        try:
            out = self.reply_fn(fb, before)
            if out is None:
                c.deferred += 1
                return 0
            body = out[2] if len(out) > 2 else None
            tm = int((self.last_rx_time - self._t0) * 1000.0)
            payload = encode_sensor((self.seqno + 1) & UINT32, tm, out[0], out[1],
                                    mtype=MSGTYPE_CORRECTION, body=body)  # fmt: skip
        except Exception:  # a failing setpoint source must never stop the I/O loop
            c.reply_errors += 1
            return 0
        work = time.perf_counter() - t_read if self.timing is not None else 0.0
        self._pending_at_send = self._peer_waiting(fb.seqno)
        sent_at = time.time() if self.timing is not None else -math.inf
        try:
            self._sock.sendto(payload, addr)
        except OSError:
            c.socket_errors += 1
            return 0
        self._sent_at = sent_at
        self.seqno = (self.seqno + 1) & UINT32
        c.replied += 1
        if self.timing is not None:
            self.timing.add(wait, work)
        return 1

    def _peer_waiting(self, answered: int) -> bool:
        """The first datagram in the socket (read with ``MSG_PEEK``: nothing consumed) is the
        peer's next request: a valid ``EgmRobot`` from the peer with a sequence number after
        ``answered``, the one being replied to (garbage, duplicates and strangers say nothing)."""
        if not self._pending.poll(0):
            return False
        try:
            data, src = self._sock.recvfrom(MAX_DATAGRAM, _PEEK)
        except BlockingIOError:
            return False
        except OSError:  # e.g. a port-unreachable report: taken by this call, so counted here
            self.counters.socket_errors += 1
            return False
        if _source(src) != self.peer:
            return False
        try:
            seqno = decode_robot(data).seqno
        except EgmDecodeError:
            return False
        return 0 < (seqno - answered) & UINT32 < 1 << 31

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
    return time.time() - arrival_stamp(ancdata)


def arrival_stamp(ancdata) -> float:
    """The kernel's arrival stamp of the datagram (``SCM_TIMESTAMPNS``: the wall clock [s]),
    NaN if absent."""
    for level, kind, raw in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(raw)
            return sec + 1e-9 * nsec
    return math.nan
