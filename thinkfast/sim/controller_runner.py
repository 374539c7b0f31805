"""A :class:`~thinkfast.sim.controller.SimController` on a real UDP socket, as a controller.

:class:`ControllerRunner` exchanges one ``EgmRobot`` / ``EgmSensor`` pair every cycle (4 ms, or
flat out) with an EGM sensor (the daemon), in a thread on ``perf_counter``, and counts what
came back in time (:class:`ExchangeStats`). The servo model and the messages are the
simulated controller's; this module owns only the socket and the clock.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import socket
import sys
import threading
import time

from thinkfast.link.egm_server import SO_TIMESTAMPNS, arrival_age

# the simulated controller's logger, as before the split (the CLIs quiet its overrun chatter)
log = logging.getLogger("thinkfast.sim.controller")


@dataclasses.dataclass
class ExchangeStats:
    """Counts and round-trip times of the UDP exchanges (``rtt_s``: one entry per reply in time).

    ``in_time_unread``: missed cycles whose reply had reached the socket before the cycle's
    deadline (kernel arrival stamp, Linux): this side, not the sensor, was late to read it.
    ``wire_s``: the same round trips to the reply's kernel arrival stamp instead of the moment
    this side read it (Linux; NaN-free, possibly shorter than ``rtt_s``): what a controller that
    is never itself delayed would see, the sensor's share of the round trip.
    ``answered``: well-formed replies applied, in their cycle (``replies``) or after it: whether
    the sensor is alive (a controller's communication timeout), however late it is.
    """

    sent: int = 0
    replies: int = 0
    answered: int = 0
    missed: int = 0
    late: int = 0
    malformed: int = 0
    in_time_unread: int = 0
    skipped: int = 0  # cycles this side could not serve in time (``keep_cycle``): never sent
    rtt_s: list[float] = dataclasses.field(default_factory=list)
    wire_s: list[float] = dataclasses.field(default_factory=list)


class ControllerRunner:
    """Runs a :class:`SimController` as an EGM client over UDP in a thread.

    Each cycle: send ``EgmRobot``, wait for the ``EgmSensor`` until the cycle ends (or
    ``reply_timeout``), apply it, step the model by ``config.dt``, sleep to the next cycle on
    ``perf_counter``. A reply that comes after its cycle is counted ``late`` (and still applied,
    as a controller would); a cycle without a reply in time is ``missed``.

    Args:
        sim: the simulated controller.
        target: ``(host, port)`` of the EGM sensor.
        rate_hz: exchanges per second; 0 runs flat out (next exchange as soon as one completes).
        n: stop after this many exchanges (None: until :meth:`stop`).
        reply_timeout: longest wait for a reply [s]; default one cycle (4 ms when flat out).
        bind: local address of the client socket.
        spin: busy-wait this long [s] for each reply before blocking (a real controller does
            not sleep between send and receive; the OS wake-up latency would otherwise be
            charged to the sensor). 0 blocks at once.
        lead: wake this long [s] before each cycle's send and busy-wait to it, so that the
            send and the timing run on a hot CPU (on a virtual machine a Python process runs
            several times slower right after a sleep). 0 sleeps to the send time.
        keep_cycle: when this side overruns by whole cycles (a loaded host), step the model
            and the sequence number through them without sending (``skipped``), as a
            controller whose cycle never stops would lose those packets: ``seqno x dt`` stays
            the wall-clock time. False: the cycles are lost from the model's time too.

    Busy-waiting holds the GIL: use ``spin`` and ``lead`` only where no other Python thread of
    the process has work to do (a sensor in the same process would be starved).
    """

    def __init__(
        self,
        sim,
        target,
        rate_hz=250.0,
        n=None,
        reply_timeout=None,
        bind=("127.0.0.1", 0),
        spin=0.0,
        lead=0.0,
        keep_cycle=False,
    ):
        self.sim, self.target, self.n, self.spin, self.lead = sim, tuple(target), n, spin, lead
        self.keep_cycle = keep_cycle
        self.period = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.reply_timeout = reply_timeout or (self.period or sim.config.dt)
        self.stats = ExchangeStats()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(bind)
        self._stamped = False  # kernel arrival stamps, to tell who was late (in_time_unread)
        self._miss_deadline: float | None = None
        if sys.platform == "linux":
            try:
                self._sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self._stamped = True
            except OSError:
                pass
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self.run, name="sim-egm-controller", daemon=True)
        self._last_warn = -math.inf

    @property
    def address(self) -> tuple[str, int]:
        """Local ``(host, port)`` the controller sends from."""
        return self._sock.getsockname()[:2]

    def start(self) -> ControllerRunner:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float | None = None) -> None:
        """Wait for the thread (if it was started) and close the socket."""
        if self._thread.ident is not None:
            self._thread.join(timeout)
        self._sock.close()

    def run(self) -> None:
        """The exchange loop (body of the thread; callable directly for a blocking run)."""
        st, sim, sock = self.stats, self.sim, self._sock
        t_next = time.perf_counter()
        while not self._stop.is_set() and (self.n is None or st.sent < self.n):
            sock.setblocking(False)
            while True:  # replies that missed their cycle
                try:
                    data, anc = self._recv()
                except OSError:
                    break
                st.late += 1
                if self._stamped and self._miss_deadline is not None:
                    arrived = time.perf_counter() - arrival_age(anc)  # NaN compares False
                    st.in_time_unread += arrived <= self._miss_deadline
                self._miss_deadline = None  # only the first late reply answers the missed cycle
                if sim.handle_sensor(data):
                    st.answered += 1
                else:
                    st.malformed += 1
            payload = sim.robot_message()
            t_send = time.perf_counter()  # before sendto: loopback may run the server inside it
            st.sent += 1
            try:
                sock.sendto(payload, self.target)
            except OSError as exc:  # e.g. no route: a lost cycle, like a lost datagram
                st.missed += 1
                self._warn(f"cannot send EgmRobot to {self.target} ({exc})")
            else:
                self._await_reply(t_send, t_send + self.reply_timeout)
            sim.step(sim.config.dt)
            if self.period:
                t_next += self.period
                now = time.perf_counter()
                if now < t_next:
                    if t_next - now > self.lead:
                        time.sleep(t_next - self.lead - now)
                    while time.perf_counter() < t_next:  # hot: busy-wait the last ``lead``
                        pass
                elif now > t_next + self.period:
                    self._warn(f"controller loop overrun by {1e3 * (now - t_next):.1f} ms")
                    if self.keep_cycle:
                        t_next = self._skip(now, t_next)
                    else:
                        t_next = now

    def _skip(self, now: float, t_next: float) -> float:
        """Step the model through the whole cycles missed by ``now`` without sending (each one
        a sequence number); returns the next cycle's send time."""
        sim, k = self.sim, int((now - t_next) / self.period)
        for _ in range(k):
            sim.header()  # the cycle's sequence number, never sent
            sim.step(sim.config.dt)
        self.stats.skipped += k
        return t_next + k * self.period

    def _await_reply(self, t_send: float, deadline: float) -> None:
        st, sock = self.stats, self._sock
        spin_end = t_send + self.spin  # busy-wait until then: no wake-up latency measured
        spinning = self.spin > 0
        if spinning:
            sock.setblocking(False)
        while True:
            now = time.perf_counter()
            if now >= deadline:
                st.missed += 1
                self._miss_deadline = deadline
                return
            try:
                if spinning and now >= spin_end:
                    spinning = False  # spun long enough: block for the rest
                if not spinning:
                    sock.settimeout(deadline - now)
                data, anc = self._recv()
            except (BlockingIOError, InterruptedError):
                continue
            except TimeoutError:
                st.missed += 1
                self._miss_deadline = deadline
                return
            except OSError:
                continue
            now = time.perf_counter()
            rtt, wire = now - t_send, now - arrival_age(anc) - t_send
            if self.sim.handle_sensor(data):
                st.replies += 1
                st.answered += 1
                st.rtt_s.append(rtt)
                if wire == wire:  # not NaN: the kernel stamped it
                    st.wire_s.append(min(max(wire, 0.0), rtt))
                return
            st.malformed += 1

    def _recv(self) -> tuple[bytes, list]:
        """One datagram and its ancillary data (the kernel's arrival stamp when ``_stamped``,
        else none)."""
        if self._stamped:
            data, anc, _, _ = self._sock.recvmsg(65535, 64)
            return data, anc
        return self._sock.recv(65535), []

    def _warn(self, message: str) -> None:
        now = time.monotonic()
        if now - self._last_warn >= 1.0:  # at most one warning per second
            self._last_warn = now
            log.warning(message)
