"""The daemon as the planner process, its EGM replies in a process of their own
(``--reply-process``).

:class:`SplitDaemon` is the :class:`~thinkfast.daemon.service.Daemon` (intake, filter, launch,
choice, executor, zenoh, recorder, live view, status) with the EGM socket handed to the reply
process (:mod:`thinkfast.reply.process`, started with ``spawn``). Instead of answering
packets it reads the reply rows (:mod:`thinkfast.reply.rows`): it makes every replan
the reply loop made on its executor too, steps the executor at each reply's controller time (so
the tree's queued edges start, throws end and the arm returns home) and mirrors the reply
loop's state onto its own control core for the status, the way home and the record. It
publishes the executor's plan (:func:`~thinkfast.control.plan.executor_plan`) whenever it
changes, and a heartbeat every loop (about every millisecond); nothing it does can delay a
reply.

With ``--cpu N`` its threads leave CPU N to the reply process; with ``--fifo P`` its planning
thread runs under SCHED_FIFO at P - 1, below the reply loop (as the daemon's own loop does at P
without ``--reply-process``). It reports a planner stall the reply loop saw
(``planner_stale``), and exits 1 with a log line when the reply process dies. A planner process
that dies leaves the reply process braking and holding (see there).
"""

from __future__ import annotations

import gc
import logging
import math
import multiprocessing
import os
import signal
import time

import numpy as np

from thinkfast.control.core import Reply
from thinkfast.control.egm_clock import ClockTick
from thinkfast.control.modes import EXECUTING
from thinkfast.control.plan import CALLS, MODES, SIZE, executor_plan, plan_key
from thinkfast.control.planner_side import PlannerSide
from thinkfast.control.safety import BRAKE_REASONS
from thinkfast.daemon.service import Daemon
from thinkfast.errors import ConfigError
from thinkfast.link.egm_address import EgmAddressError
from thinkfast.link.egm_server import EgmCounters
from thinkfast.link.reply_times import ReplyTimes
from thinkfast.link.rt_thread import set_fifo
from thinkfast.reply import process as reply_process
from thinkfast.reply.rows import (
    CALL,
    COL,
    CORE_COUNTS,
    EGM_COUNTS,
    EVENT,
    EVENTS,
    REPLY,
    WIDTH,
    ip_text,
)  # fmt: skip
from thinkfast.reply.shared_plan import RowRing, Seqlock

log = logging.getLogger("thinkfast.run")
START_TIMEOUT = 120.0  # s for the reply process to import, bind and report


class RemoteEgm:
    """What the daemon reads of its EGM server, kept from the reply rows."""

    def __init__(self, address, dt: float):
        self.address = tuple(address)
        self.counters = EgmCounters()
        self.peer: tuple[str, int] | None = None
        self.foreign_sources: dict[str, int] = {}
        self.timing = ReplyTimes(late_after=dt)
        self.behind = False

    def close(self) -> None:
        """Nothing to close here: the reply process owns the socket."""


class SplitDaemon(Daemon):
    """The planner process (module doc); ``stall``: ``(seconds, after)`` to stall the loop once,
    ``after`` seconds after the first throw began to execute (a test hook)."""

    def __init__(self, tree, robot, cfg, planner, endpoints, zenoh_conf, stall=None, **kwargs):
        self.stall = stall
        self._zenoh = (str(zenoh_conf), endpoints.key_prefix)  # for the reply process's status
        super().__init__(tree, robot, cfg, planner, endpoints, zenoh_conf, **kwargs)
        self.side = PlannerSide(self.executor)  # the reply loop's replans made here too
        self.plan_id = 0
        self.epoch = 0  # replans of the reply loop made here too
        self._plan_key: tuple | None = None
        self._executing: float | None = None  # when the first throw was executed (stall hook)
        self.stale_events = 0
        self.lap_max = 0.0  # the longest planner loop [s]
        self._slow_said = -math.inf

    def _open_link(self, endpoints):
        """Start the reply process; it binds the EGM socket and reports its address."""
        if endpoints.link != "egm":
            raise ConfigError("--reply-process", None, f"the reply process speaks EGM, not "
                              f"--link {endpoints.link}")  # fmt: skip
        self.plan_block = Seqlock(SIZE)
        self.ring = RowRing(WIDTH)
        ctx = multiprocessing.get_context("spawn")
        mine, theirs = ctx.Pipe()
        args = (
            theirs, endpoints.egm_bind, endpoints.egm_controller, endpoints.egm_handover,
            self.robot, self.cfg, self.plan_block.name, self.ring.name, os.getpid(), self.cpu,
            self.fifo, self.cycle.spin_ahead, self._zenoh,
        )  # fmt: skip
        self.proc = ctx.Process(target=reply_process.main, args=args, name="thinkfast-reply")
        self.proc.start()
        theirs.close()
        if not mine.poll(START_TIMEOUT):
            self.proc.kill()
            raise EgmAddressError("the EGM reply process did not start")
        msg = mine.recv()
        if msg[0] != "ready":
            self.proc.join()
            raise EgmAddressError(msg[1])
        self.reply_pid = msg[2]
        return RemoteEgm(msg[1], self.cfg.safety.dt)

    # -------------------------------------------------------------- rows
    def _mirror(self, row: np.ndarray) -> None:
        kind, t = row[COL["type"]], float(row[COL["t"]])
        if kind == CALL:
            self._call(CALLS[int(row[COL["code"]])], t, row)
        elif kind == EVENT:
            code, reason = int(row[COL["code"]]), int(row[COL["reason"]])
            name = EVENTS[code] if code >= 0 else "event"
            detail = {"source": "reply_process"}
            if reason >= 0:
                detail["reason"] = BRAKE_REASONS[reason]
            if name == "planner_stale":
                self.stale_events += 1
                log.warning("the reply process braked: no word from the planner for %.3f s",
                            self.cfg.safety.planner_timeout)  # fmt: skip
            self._event(t, name, detail)
        elif kind == REPLY:
            self._reply_row(t, row)

    def _call(self, name: str, t: float, row: np.ndarray) -> None:
        q, qd, qdd = row[COL["q"]], row[COL["qd"]], row[COL["qdd"]]
        self.epoch += 1
        try:
            self.side.call(name, t, q, qd, qdd)
        except Exception as exc:  # the reply loop goes on from its own replan
            self._planner_error(name, exc)

    def _reply_row(self, t: float, row: np.ndarray) -> None:
        ctl, sup, egm = self.control, self.supervisor, self.link
        now = float(row[COL["now"]])
        q, qd, qdd, q_meas = (np.array(row[COL[k]]) for k in ("q", "qd", "qdd", "q_meas"))
        mode = MODES[int(row[COL["mode"]])]
        self.last_rx = now
        ctl.clock.t = t
        sup.q, sup.qd, sup.qdd = q, qd, qdd
        brake = int(row[COL["brake"]])
        sup.brake_reason = BRAKE_REASONS[brake] if brake >= 0 else None
        sup.ticks, sup.intervened = int(row[COL["sup_ticks"]]), int(row[COL["sup_intervened"]])
        for k in sup.counts:
            sup.counts[k] = int(row[COL[f"kind_{k}"]])
        for name in CORE_COUNTS:
            setattr(ctl, name, int(row[COL[name]]))
        ctl.standby, ctl.latched = bool(row[COL["standby"]]), bool(row[COL["latched"]])
        ctl.fault_count = int(row[COL["fault_count"]])
        ctl.last = Reply(q, qd, mode, ClockTick(t, self.cfg.safety.dt, False, False))
        for name in EGM_COUNTS:
            setattr(egm.counters, name, int(row[COL[name]]))
        if row[COL["peer_ip"]] >= 0:
            egm.peer = (ip_text(row[COL["peer_ip"]]), int(row[COL["peer_port"]]))
        egm.timing.add(float(row[COL["wait"]]), float(row[COL["work"]]))
        state = tuple(bool(row[COL[k]]) for k in ("motors_on", "mci_running", "rapid_running"))
        if state != self._controller_key:
            self._controller_key = state
            self.controller_state = {**dict(zip(("motors_on", "mci_running", "rapid_running"),
                                                state, strict=True)),
                                     "ready": bool(row[COL["ready"]])}  # fmt: skip
            self._event(t, "controller_state", self.controller_state)
        if row[COL["stepped"]]:  # the executor's episode at this controller time
            try:
                self.side.step(t, q, qd, qdd)  # its wrist where the reply loop's is
            except Exception as exc:
                self._planner_error("setpoint", exc)
        self._watch_throw(t)
        self._watch_stage(t)
        self.outbox.append((t, q, qd, mode, q_meas))
        self.recorder.egm(now, int(row[COL["seqno"]]), q_meas, q, qd, brake >= 0)

    def _rows_lost(self, rows: np.ndarray) -> None:
        """Rows were overwritten before they were read (a very long stall here): plan on from
        the newest reply's commanded state, in the reply loop's epoch."""
        replies = rows[rows[:, COL["type"]] == REPLY]
        if not len(replies):
            return
        row = replies[-1]
        self.epoch = int(row[COL["epoch"]])
        log.warning("%d reply rows lost: planning on from the last command", self.ring.lost)
        try:
            self.side.call("resync", float(row[COL["t"]]), row[COL["q"]], row[COL["qd"]],
                           row[COL["qdd"]])  # fmt: skip
        except Exception as exc:
            self._planner_error("resync", exc)

    def _plan_time(self, now: float) -> float:
        """The controller time of the reply loop's next cycle (it runs ahead of the rows read)."""
        if not self.connected(now):
            return now
        dt = self.cfg.safety.dt
        return self.control.clock.t + dt * max(1, math.ceil((now - self.last_rx) / dt))

    def _publish(self) -> None:
        """The executor's plan, when it changed since the last one published."""
        ex = self.executor  # the plan is read off it in control.plan
        key = plan_key(ex, self.epoch)
        if key == self._plan_key:
            return
        self._plan_key = key
        self.plan_id += 1
        self.plan_block.write(executor_plan(ex, self.plan_id, self.epoch))

    # -------------------------------------------------------------- main loop
    def run(self) -> int:
        """Plan until SIGINT/SIGTERM (the reply process then brakes and ends), or until the
        reply process dies (exit 1)."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)
        log.info("serving %s on %s from reply process %d, planner %s", self.link_text,
                 self.link_where(), self.reply_pid, self.planner)  # fmt: skip
        if self.cpu is not None:  # the reply process's CPU is left to it
            others = os.sched_getaffinity(0) - {self.cpu}
            _move_threads(others)
            self.recorder.move_writer(others)
        if self.fifo is not None:  # this thread (the planning) just below the reply loop
            set_fifo(max(1, self.fifo - 1))
        self._event(time.time(), "start", self.summary())
        gc.collect()
        gc.freeze()  # the tree and the rest of the start-up never collected: short collections
        code, told = 0, False
        next_status = time.time()
        try:
            while True:
                lap = _Lap()
                lost = self.ring.lost
                rows = self.ring.take()
                for row in rows:
                    self._mirror(row)
                if self.ring.lost != lost:
                    self._rows_lost(rows)
                self.plan_block.beat(time.monotonic())  # any word counts (deadlines)
                self._flush_outbox()
                self._watch_peer()
                lap("rows")
                self._take_detections(True)
                self.plan_block.beat(time.monotonic())
                lap("detections")
                self.home.service(self.control, lambda now: math.inf, self._plan_time)
                self._publish()
                self.plan_block.beat(time.monotonic())
                lap("plan")
                now = time.time()
                if now >= next_status:
                    self.zio.publish_status(self.status(now))
                    next_status = now + 1.0 / self.cfg.status_rate
                if self.view is not None:
                    self.view.service(now, self.last_rx, self.control, math.inf)
                self.recorder.service()
                lap("status")
                self._stall(now)
                self._slow_lap(lap, len(rows))
                if self.stop_reason is not None and not told:
                    told = True
                    os.kill(self.proc.pid, signal.SIGTERM)  # it brakes, then ends
                if not self.proc.is_alive():
                    if not told:
                        why = f"exit code {self.proc.exitcode}"
                        log.error("the EGM reply process %d died (%s): the controller gets no "
                                  "answers; stopping", self.proc.pid, why)  # fmt: skip
                        code = 1
                    break
                time.sleep(0.001)
        finally:
            if self.proc.is_alive():
                self.proc.terminate()
            self.proc.join(5.0)
            self.zio.publish_status({**self.status(time.time()), "exiting": True})
            self.recorder.close()
            self.zio.close()
            if self.view is not None:
                self.view.close()
            self.plan_block.close()
            self.ring.close()
        log.info("stopped (%s)", self.stop_reason or "reply process ended")
        return code

    def _slow_lap(self, lap: _Lap, rows: int) -> None:
        """Keep the longest loop, and say where the time went in one that took more than half
        the planner timeout (at most every 10 s)."""
        total = lap.total()
        self.lap_max = max(self.lap_max, total)
        if total > 0.5 * self.cfg.safety.planner_timeout and time.time() > self._slow_said + 10:
            self._slow_said = time.time()
            parts = ", ".join(f"{k} {1e3 * v:.1f} ms" for k, v in lap.parts)
            log.warning("slow planner loop: %.1f ms (%s; %d rows)", 1e3 * total, parts, rows)

    def _take_detections(self, replied: bool) -> None:
        """Every queued detection, at once: nothing here delays a reply."""
        self.pending.extend(self.zio.drain())
        while self.pending:
            self._take(self.pending.popleft(), time.time())
            self.plan_block.beat(time.monotonic())  # word with every detection handled

    def _stall(self, now: float) -> None:
        if self.stall is None:
            return
        if self._executing is None and self.control.state().mode == EXECUTING:
            self._executing = now
        seconds, after = self.stall
        if self._executing is not None and now - self._executing >= after:
            self.stall = None
            log.warning("test hook: stalling the planner for %.3f s", seconds)
            time.sleep(seconds)

    def status(self, now: float) -> dict:
        out = super().status(now)
        out["reply_process"] = {
            "pid": self.reply_pid, "alive": self.proc.is_alive(), "plan_id": self.plan_id,
            "rows_lost": self.ring.lost, "planner_stale": self.stale_events,
            "loop_max_ms": round(1e3 * self.lap_max, 1),
        }  # fmt: skip
        return out


def _move_threads(cpus: set[int]) -> None:
    """Every thread of this process (zenoh's included) onto ``cpus`` (none: left as they are)."""
    if not cpus:
        return
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:  # the thread has just ended
            pass


class _Lap:
    """Durations of the phases of one planner loop [s]."""

    def __init__(self):
        self.t0 = self.t = time.perf_counter()
        self.parts: list[tuple[str, float]] = []

    def __call__(self, name: str) -> None:
        now = time.perf_counter()
        self.parts.append((name, now - self.t))
        self.t = now

    def total(self) -> float:
        return self.t - self.t0
