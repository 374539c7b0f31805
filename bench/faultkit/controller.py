"""A faulty ABB controller: the simulator's servo model on its own 250 Hz clock, injected faults.

:class:`FaultController` runs in a thread. Its clock is a grid of 4 ms cycles anchored on
``perf_counter``: cycle ``k`` is due at ``t0 + k dt`` and its ``EgmRobot`` carries
``tm = tm0 + 4 k`` ms and ``seqno`` counts the cycles (+1 per cycle, like a real controller whose
packets the network lost). A loop that wakes more than half a cycle late (this host stalled it,
or a fault paused it) skips to the cycle that is due, so ``tm`` and ``seqno`` jump by the cycles
lost, as a real controller's would; the servo (:class:`SimController`) integrates every cycle of
it with the last reference.

:meth:`jitter` makes it a controller that is not hard real-time (a virtual controller): ``tm``
jitters around the cycle in whole ms and repeats (:class:`~thinkfast.sim.controller.ClockJitter`),
and its pauses stop its servo too: after one, ``tm`` has jumped by the pause while the next
cycle is the next one (``seqno`` +1, the servo one cycle on).

Each cycle: read the replies that arrived during the previous cycle (kernel arrival stamps, so a
late read of this process never moves a reply to another cycle), apply the last valid one to the
servo (the controller's rule: a cycle without a reply keeps the previous command), step the servo,
then send the next ``EgmRobot``. One row per cycle goes to :attr:`rows` (columns in
:mod:`bench.faultkit.rows`) for the independent checker.

Faults (set from any thread, applied from the next cycle): ``duplicate`` (each ``EgmRobot``
sent twice), ``malformed`` (extra malformed datagrams from the peer's socket, per cycle),
:meth:`gap` (stop sending for a while: a silence, or a host pause), :meth:`random_pauses`,
:meth:`freeze` (the arm stops following: q stays while commands move), :meth:`absurd` (absurd
feedback values), :meth:`reset_seqno`, and a soft servo through the ``servo`` config.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import socket
import threading
import time

import numpy as np

from bench.faultkit import rows as R
from bench.faultkit.egm_pb import decode_reply, robot_message
from bench.faultkit.senders import malformed_datagram, recv_stamped
from thinkfast.link.egm_server import SO_TIMESTAMPNS
from thinkfast.sim.controller import ClockJitter, ServoConfig, SimController, Stamps


class FaultController:
    """Simulated controller with faults (see the module doc).

    Args:
        target: ``(host, port)`` of the daemon's EGM socket (loopback only).
        servo: servo model and limits (a soft servo: larger ``tau_v``/``delay``, smaller gains).
        q0: starting joints [rad] (6,).
        seed: randomness of the injected faults.
        history_s: keep this long of the arm's wall-clock history for the judge [s].
        q_limits: ``(q_lower, q_upper)`` [rad] (6,) each: replies outside are counted per cycle.
        fifo: run the loop's thread under SCHED_FIFO at this priority when the OS allows it (a
            real controller keeps its cycle; this one then stalls only with the host). It sleeps
            between cycles, so it never starves the machine. :attr:`realtime` says if it took.
    """

    def __init__(
        self, target, servo=ServoConfig(), q0=None, seed=0, history_s=120.0, q_limits=None,
        fifo: int | None = None,
    ):  # fmt: skip
        if not str(target[0]).startswith("127."):
            raise ValueError(f"the fault controller talks to loopback only, not {target[0]}")
        self.target, self.dt = (target[0], int(target[1])), servo.dt
        self.sim = SimController(servo, q0=q0, max_history=1)
        self.rng = np.random.default_rng(seed)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.setblocking(False)
        self.rows = R.RowBuffer()
        self.fifo, self.realtime = fifo, False
        self.q_limits = None if q_limits is None else tuple(np.asarray(x) for x in q_limits)
        self.wall: collections.deque = collections.deque(maxlen=int(history_s / self.dt))
        self.last_cmd: np.ndarray | None = None  # q of the last applied reply [rad]
        self.tm0 = int(self.rng.integers(1_000, 1_000_000))  # the controller has been up a while
        self.duplicate = False
        self.malformed = 0.0  # malformed datagrams per cycle (mean; Poisson)
        self.malformed_sent = 0
        self._seqno = 0
        self._k_sent: int | None = None  # cycle of the last EgmRobot
        self._stamps: Stamps | None = None  # jitter mode: tm stamps
        self._shift = 0.0  # jitter mode: the cycle grid moved by the pauses so far [s]
        self._gaps: collections.deque = collections.deque()  # (seconds, flag)
        self._pauses: tuple[float, float, float] | None = None
        self._next_pause = math.inf
        self._freeze_left = 0  # cycles
        self._frozen_q: np.ndarray | None = None
        self._absurd: collections.deque = collections.deque()  # per-cycle q offsets or values
        self._seq_reset = False
        self.gap_log: list[tuple[float, float, int]] = []  # (wall start, wall end, flag)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fault-controller", daemon=True)

    # ------------------------------------------------------------------ fault controls
    def gap(self, seconds: float, flag: int = R.SILENCE) -> None:
        """Send nothing for ``seconds`` from the next cycle (the servo keeps integrating)."""
        self._gaps.append((float(seconds), flag))

    def random_pauses(self, mean_interval: float, lo: float, hi: float) -> None:
        """Pause the loop for ``U(lo, hi)`` seconds at exponential intervals (mean [s])."""
        self._pauses = (mean_interval, lo, hi)
        self._next_pause = time.perf_counter() + self.rng.exponential(mean_interval)

    def freeze(self, seconds: float) -> None:
        """The arm stops following for ``seconds``: q stays, velocity zero, commands ignored."""
        self._freeze_left = max(1, round(seconds / self.dt))

    def absurd(self, values: list[np.ndarray]) -> None:
        """Report these joint values [rad] (6,) instead of the measured ones, one per cycle."""
        self._absurd.extend(np.asarray(v, dtype=float) for v in values)

    def jitter(self, clock: ClockJitter, pauses: tuple[float, float, float] | None = None) -> None:
        """From the next cycle: ``tm`` jitters and repeats as ``clock`` says, and pauses (``mean
        interval, lo, hi`` [s], as :meth:`random_pauses`) stop the servo and the cycle grid
        instead of skipping cycles (``tm`` jumps by the pause)."""
        self._stamps = Stamps(dataclasses.replace(clock, stall_rate=0.0))
        if pauses is not None:
            self.random_pauses(*pauses)

    def reset_seqno(self) -> None:
        """Restart ``seqno`` from 0 at the next message (``tm`` continues)."""
        self._seq_reset = True

    # ------------------------------------------------------------------ thread
    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()[:2]

    def start(self) -> FaultController:
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(timeout)
        self.sock.close()

    def history(self, since: float) -> tuple[np.ndarray, np.ndarray]:
        """Wall times [s] (N,) and joint angles [rad] (N, 6) of the arm from ``since`` on."""
        rows = [r for r in list(self.wall) if r[0] >= since]
        return np.array([r[0] for r in rows]), np.array([r[1] for r in rows]).reshape(-1, 6)

    def _run(self) -> None:
        if self.fifo is not None:
            try:  # this thread only
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.fifo))
                self.realtime = True
            except (AttributeError, OSError):
                pass
        dt, sim = self.dt, self.sim
        t0, w0 = time.perf_counter(), time.time()
        k_prev, row = -1, None
        while not self._stop.is_set():
            k = k_prev + 1
            t_pause = time.perf_counter()
            flag = self._maybe_pause()
            if flag and self._stamps is not None:  # its servo stopped too: the grid moves on
                lost = time.perf_counter() - t_pause
                t0, self._shift = t0 + lost, self._shift + lost
            due = t0 + k * dt
            now = time.perf_counter()
            if due > now:
                time.sleep(due - now)
                now = time.perf_counter()
            if now > due + 0.5 * dt and self._stamps is not None:  # jitter mode: all stopped
                t0, self._shift = t0 + now - due, self._shift + now - due
                flag |= R.LATE if not flag else 0
            elif (
                now > due + 0.5 * dt
            ):  # stalled (by a fault or by this host): skip to the due cycle
                k = int(math.floor((now - t0) / dt + 0.5))
                flag |= R.LATE if not flag else 0
            t_send = time.time()
            cmd = None
            if row is not None:
                cmd = self._collect(row, t_send)
                self.rows.append(row)
            if cmd is not None:
                sim.command(cmd[0], cmd[1])  # received in the previous cycle (its start time)
            for _ in range(k - k_prev if k_prev >= 0 else 0):
                self._step()
            row = self._send(k, t_send, w0 + self._shift + k * dt, flag)
            k_prev = k
        if row is not None:
            self._collect(row, time.time())
            self.rows.append(row)

    def _maybe_pause(self) -> int:
        flag = 0
        if self._gaps:
            seconds, flag = self._gaps.popleft()
        elif time.perf_counter() >= self._next_pause and self._pauses is not None:
            mean, lo, hi = self._pauses
            seconds, flag = float(self.rng.uniform(lo, hi)), R.PAUSE
            self._next_pause = time.perf_counter() + seconds + self.rng.exponential(mean)
        if flag:
            w = time.time()
            time.sleep(seconds)
            self.gap_log.append((w, time.time(), flag))
        return flag

    def _step(self) -> None:
        sim = self.sim
        if self._freeze_left > 0:
            if self._frozen_q is None:
                self._frozen_q = sim.q.copy()
            sim.step(self.dt)
            sim.q, sim.qd = self._frozen_q.copy(), np.zeros(6)
            self._freeze_left -= 1
        else:
            self._frozen_q = None
            sim.step(self.dt)

    def _send(self, k: int, t_send: float, t_grid: float, flag: int) -> np.ndarray:
        sim = self.sim
        q_true = sim.q.copy()
        self.wall.append((t_grid, q_true))
        q_sent = q_true
        if self._absurd:
            q_sent, flag = self._absurd.popleft(), flag | R.ABSURD
        step = 1 if self._k_sent is None else k - self._k_sent
        self._k_sent = k
        if self._seq_reset:
            self._seq_reset, self._seqno, step, flag = False, -1, 1, flag | R.SEQ_RESET
        self._seqno += step
        tm = self.tm0 + 4 * k
        if self._stamps is not None:
            tm = self.tm0 + self._stamps.tm(k * self.dt + self._shift, self.dt)
        msg = robot_message(self._seqno, tm, q_sent, unix_time=t_send)
        copies = 2 if self.duplicate else 1
        flag |= R.DUP if copies == 2 else 0
        flag |= R.FROZEN if self._frozen_q is not None else 0
        try:
            for _ in range(copies):
                self.sock.sendto(msg, self.target)
            n_bad = int(self.rng.poisson(self.malformed)) if self.malformed > 0 else 0
            for _ in range(n_bad):
                self.sock.sendto(malformed_datagram(self.rng, msg), self.target)
            self.malformed_sent += n_bad
            flag |= R.MALFORMED if n_bad else 0
        except OSError:
            flag |= R.SEND_FAILED
        return R.new_row(k, tm, self._seqno, t_send, t_grid, flag, q_sent, q_true, sim.qd)

    def _collect(self, row: np.ndarray, t_end: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Read the replies of the cycle that ``row`` opened; the last valid one is applied."""
        applied = None
        for data, t_arr in recv_stamped(self.sock):
            rep = decode_reply(data)
            ok = rep is not None and rep.q is not None and rep.q.size == 6
            ok = ok and (rep.qd is None or rep.qd.size == 6)
            if not ok:
                row[R.N_BAD] += 1
                continue
            qd = rep.qd if rep.qd is not None else np.zeros(6)
            if not (np.isfinite(rep.q).all() and np.isfinite(qd).all()):
                row[R.N_NONFINITE] += 1
                continue
            if t_arr > t_end:  # (cannot happen: read before the next send) keep it honest
                t_arr = t_end
            row[R.N_VALID] += 1
            if self.q_limits is not None:
                lo, hi = self.q_limits
                row[R.N_OUTSIDE] += bool((rep.q < lo).any() or (rep.q > hi).any())
            applied = (rep, qd, t_arr)
        if applied is None:
            return None
        rep, qd, t_arr = applied
        R.set_reply(row, t_arr, rep.q, qd, rep.seqno, rep.tm, rep.mtype)
        self.last_cmd = rep.q
        return rep.q, qd
