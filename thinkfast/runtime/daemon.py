"""The ``thinkfast-run`` daemon: one thread, EGM first.

The loop waits on the EGM socket; every ``EgmRobot`` is answered at once with the executor's
setpoint for now, passed through the safety supervisor (the last stage before the wire). Between
two EGM packets (4 ms) it drains the zenoh detection queue (filter, crossing, values, backup),
publishes the mirrored setpoints and the status. Signals only set a flag: the loop brakes
smoothly while the controller still talks to it, then exits 0.

Nothing may delay a reply, so the other work runs right after one: the first queued detection
is taken at once after a reply, further ones only while, at the cost of the slowest recent one,
they end before the next ``EgmRobot``'s window opens (:mod:`thinkfast.runtime.cycle`). The
mirrored setpoints and the status go out in the same place, and so do garbage collections
(automatic collection is off while serving; the interpreter's own thresholds decide).

When the window opens, shortly before the next ``EgmRobot`` is due, the reply is prepared: the
executor's setpoint for the time the packet is due, filtered by the supervisor ahead, and the
EGM codec warmed up; the reply itself then only decodes, runs the supervisor's checks on the
feedback and the traffic, and encodes. By default the loop sleeps in ``poll`` (1 ms at a time)
until a packet comes; with ``spin_ahead`` it spins on the socket inside the window (on a
virtual machine Python runs several times slower right after a sleep), and with ``spin_ahead
>= dt`` (busy polling) all the time, at the cost of a whole core. ``cpu`` pins the loop's thread
to one core (and zenoh's threads to the others), ``fifo`` puts it under SCHED_FIFO
(:mod:`thinkfast.runtime.rt_thread`). docs/BENCHMARKS.md has the figures.
"""

from __future__ import annotations

import collections
import gc
import json
import logging
import math
import select
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thinkfast.compile.tree import ActionTree
from thinkfast.robot.model import Robot
from thinkfast.runtime.config import RunConfig
from thinkfast.runtime.cycle import SPIN_LATE, Cycle
from thinkfast.runtime.egm_server import EgmServer
from thinkfast.runtime.executor import FAULT, IDLE, Executor
from thinkfast.runtime.intake import Intake
from thinkfast.runtime.planner import runtime_tree
from thinkfast.runtime.recorder import Recorder
from thinkfast.runtime.rt_thread import pin_thread, set_fifo
from thinkfast.runtime.safety import SafetySupervisor, robot_limits
from thinkfast.runtime.zenoh_io import ZenohIO

log = logging.getLogger("thinkfast.run")
STATUS_COST = 0.001  # s set aside for a status message (JSON, timing percentiles)


@dataclass(frozen=True)
class Endpoints:
    """I/O options of the daemon (from the command line)."""

    egm_bind: str = "0.0.0.0:6510"
    egm_controller: str | None = None
    key_prefix: str = "thinkfast"
    record: Path | None = None


class Daemon:
    """Composes executor, supervisor, EGM server, zenoh and recorder (see the module doc)."""

    def __init__(
        self,
        tree: ActionTree,
        robot: Robot,
        cfg: RunConfig,
        planner: str,
        endpoints: Endpoints,
        zenoh_conf,
        spin_ahead: float = 0.0,
        cpu: int | None = None,
        fifo: int | None = None,
    ):
        self.cfg, self.robot, self.planner = cfg, robot, planner
        self.cycle, self.cpu, self.fifo = Cycle(cfg.safety.dt, spin_ahead), cpu, fifo
        self.executor = Executor(runtime_tree(tree, robot, cfg), robot, cfg, planner)
        self.limits = robot_limits(robot, cfg.safety.position_margin)
        self.supervisor = SafetySupervisor(self.limits, cfg.safety, robot.home)
        self.intake = Intake(cfg.camera, cfg.detections)
        self.egm = EgmServer(endpoints.egm_bind, self._reply, endpoints.egm_controller, timing=True)
        self.zio = ZenohIO(zenoh_conf, endpoints.key_prefix)
        self.recorder = Recorder(
            endpoints.record,
            {
                "planner": planner,
                "tree_config_sha256": tree.meta.get("config_sha256", ""),
                "run_config": json.dumps(_plain(cfg)),
                "started": time.time(),
            },
        )
        self.stop_reason: str | None = None
        self.synced = False  # the supervisor starts from the first measured joints
        self.last_rx = -math.inf
        self.outbox: list[tuple[float, np.ndarray, np.ndarray, str]] = []
        self.decision_ms = 0.0
        self.planner_errors = 0
        self.pending: collections.deque[bytes] = collections.deque()  # drained, not yet taken
        self.detection_cost = 0.001  # s, decaying maximum of recent detection handling times
        self.next_req: tuple[float, np.ndarray, np.ndarray] | None = None  # see _prepare
        self.prepared_for = -math.inf  # last_rx of the cycle _prepare ran in

    # -------------------------------------------------------------- EGM path
    def _reply(self, fb) -> tuple[np.ndarray, np.ndarray]:
        now = time.time()
        gap = now - self.last_rx
        self.last_rx = now
        if not self.synced:
            self.supervisor.reset(fb.q_rad)
            self.executor.start_from(np.array(fb.q_rad), now)
            self.synced = True
            gap = 0.0
        prepared, self.next_req = self.next_req, None
        try:
            if prepared is not None and now <= prepared[0] + SPIN_LATE:
                _, q_req, qd_req = prepared  # see _prepare
            else:
                q_req, qd_req = self.executor.setpoint(now)
        except Exception:  # a planner bug must cost a smooth stop, never a missing reply
            q_req = qd_req = None  # the supervisor brakes on a non-finite request
            self.planner_errors += 1
            if self.planner_errors == 1 or self.planner_errors % 100 == 0:
                log.exception("setpoint error %d: braking", self.planner_errors)
        if self.stop_reason is not None:
            self.supervisor.request_brake("signal")
        cmd = self.supervisor.step(q_req, qd_req, q_meas=fb.q_rad, egm_age=gap)
        if cmd.stopped and self.supervisor.brake_reason == "traffic" and gap <= 0.01:
            self.supervisor.release()  # traffic is back and the arm stands: plan from here
            self.executor.recover(np.array(cmd.q), now)
        elif cmd.braking and self.supervisor.brake_reason in ("deviation", "nonfinite"):
            self.executor.mode = FAULT
        mode = "brake" if cmd.braking else self.executor.mode
        self.outbox.append((now, cmd.q, cmd.qd, mode))
        self.recorder.egm(now, fb.seqno, fb.q_rad, cmd.q, cmd.qd, cmd.braking)
        return cmd.q, cmd.qd

    # -------------------------------------------------------------- main loop
    def run(self) -> int:
        """Serve until SIGINT/SIGTERM, then brake and return 0."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)
        poller = select.poll()
        poller.register(self.egm.fileno(), select.POLLIN)
        gc.collect()
        gc.freeze()  # nothing allocated so far is ever collected: shorter GC pauses
        gc.disable()  # collections run after replies (_collect_garbage), never inside one
        status_period = 1.0 / self.cfg.status_rate
        next_status = time.time()
        spin = "always" if self.cycle.busy else f"{1e3 * self.cycle.spin_ahead:g} ms ahead"
        log.info(
            "serving EGM on %s:%d, planner %s, spinning %s", *self.egm.address, self.planner,
            spin if self.cycle.spin_ahead > 0 else "never",
        )  # fmt: skip
        cycle = self.cycle
        try:
            if self.cpu is not None:  # here: zenoh's threads are running (they move away)
                pin_thread(self.cpu)
            if self.fifo is not None:  # this thread only
                set_fifo(self.fifo)
            while True:
                since = time.time() - self.last_rx
                if self.prepared_for != self.last_rx and self.synced and cycle.in_window(since):
                    self._prepare()
                wait_ms = cycle.wait_ms(since)
                replied = bool(poller.poll(wait_ms)) and self.egm.poll(16) > 0  # replies at once
                self._flush_outbox()
                self._take_detections(replied)
                now = time.time()
                if now >= next_status and self._time_left(now) > STATUS_COST:
                    self.zio.publish_status(self.status(now))
                    next_status = now + status_period
                self._collect_garbage(now)
                if self.stop_reason is not None and self._may_exit(now):
                    break
        finally:
            gc.enable()
            gc.unfreeze()
            self.zio.publish_status(
                {
                    **self.status(time.time()),
                    "state": "idle" if self.executor.mode == IDLE else self.executor.mode,
                    "exiting": True,
                }
            )
            self.recorder.close()
            self.egm.close()
            self.zio.close()
        log.info("stopped (%s)", self.stop_reason)
        return 0

    def _on_signal(self, signum, _frame) -> None:
        self.stop_reason = signal.Signals(signum).name

    def _may_exit(self, now: float) -> bool:
        silent = now - self.last_rx > self.cfg.safety.traffic_timeout
        return silent or not self.supervisor.qd.any()

    def _flush_outbox(self) -> None:
        for stamp, q, qd, mode in self.outbox:
            self.zio.publish_setpoint(stamp, q, qd, mode)
        self.outbox.clear()

    def _prepare(self) -> None:
        """Compute the next reply's setpoint ahead, for the time its EgmRobot is due, and filter
        it through the supervisor (:meth:`SafetySupervisor.prepare`): the reply then has only
        the supervisor's feedback and traffic checks left to run. Taking a detection voids it.
        Then warm the EGM codec (:meth:`EgmServer.warm`): spinning, the reply path stays in
        the caches until the packet comes."""
        self.prepared_for = self.last_rx
        t_due = self.last_rx + self.cfg.safety.dt
        try:
            q_req, qd_req = self.executor.setpoint(t_due)
        except Exception:  # the reply calls it again, counts the error and brakes
            return
        self.next_req = (t_due, q_req, qd_req)
        self.supervisor.prepare(q_req, qd_req)
        self.egm.warm()

    def _time_left(self, now: float) -> float:
        """Seconds of work that still end before the next EgmRobot's window opens."""
        return self.cycle.time_left(now - self.last_rx)

    def _collect_garbage(self, now: float) -> None:
        """Collect as the interpreter would (same thresholds), where it cannot delay a reply."""
        counts, limits = gc.get_count(), gc.get_threshold()
        if counts[0] < limits[0] or self._time_left(now) < 0.001:
            return
        gc.collect(0 if counts[1] < limits[1] else 1 if counts[2] < limits[2] else 2)

    def _take_detections(self, replied: bool) -> None:
        """Take queued detections: the first at once if a reply just left, the others while
        each still fits before the next EgmRobot (see the module doc). Zenoh is not even
        asked when none would fit: its queue shares a lock with zenoh's own threads, which
        run at a lower priority than a real-time EGM loop."""
        pending = self.pending
        if not replied and self._time_left(time.time()) < self.detection_cost:
            return
        pending.extend(self.zio.drain())
        while pending:
            now = time.time()
            if not replied and self._time_left(now) < self.detection_cost:
                return
            replied = False
            t0 = time.perf_counter()
            self._take(pending.popleft(), now)
            spent = time.perf_counter() - t0
            self.detection_cost = max(spent, 0.99 * self.detection_cost, 1e-4)

    def _take(self, payload: bytes, now: float) -> None:
        """One detection payload received at ``now``: intake, recorder, filter and planner."""
        self.recorder.raw(now, payload)
        det = self.intake.take(payload, now)
        if det is None:
            return
        self.next_req, self.prepared_for = None, -math.inf  # plan changes: prepare again
        self.recorder.detection(now, det.stamp, det.position, det.seq)
        t0 = time.perf_counter()
        ex = self.executor
        try:
            ex.on_detection(now, det.stamp, det.position)
        except Exception:  # a planner bug must not stop the EGM loop: stop the arm instead
            self.planner_errors += 1
            if self.planner_errors == 1 or self.planner_errors % 100 == 0:
                log.exception("planner error %d: braking", self.planner_errors)
            self.supervisor.request_brake("nonfinite")
            return
        self.decision_ms = 1e3 * (time.perf_counter() - t0)
        if self.recorder.enabled and ex.belief.n_meas >= 2:  # the crossing only for the record
            c = ex.tree.crossing(ex.belief.mean, ex.belief.cov, self.cfg.filter.gravity)
            self.recorder.belief(now, ex.belief, c)
        d = ex.decision
        if d is not None and d.backup is not None:
            node = ex.node
            self.recorder.decision(
                now, ex.mode, node, float(d.backup.value[node]), int(d.backup.best_goal)
            )

    def status(self, now: float) -> dict:
        """The status message (INTERFACES.md: at least stamp and state)."""
        ex = self.executor
        d = ex.decision
        value = float(d.backup.value[ex.node]) if d is not None and d.backup is not None else None
        return {
            "stamp": now,
            "state": "fault" if ex.mode == FAULT else ex.mode,
            "planner": self.planner,
            "throws": ex.episodes,
            "node": ex.node,
            "value": value,
            "decision_ms": round(self.decision_ms, 3),
            "detections": self.intake.as_dict(),
            "egm": vars(self.egm.counters).copy(),
            "egm_connected": now - self.last_rx < self.cfg.safety.traffic_timeout,
            "safety": {k: v for k, v in self.supervisor.counts.items() if v},
            "braking": self.supervisor.braking,
            "planner_errors": self.planner_errors,
            "egm_timing": self.egm.timing.summary(),
        }


def _plain(obj):
    from thinkfast.config import to_dict

    return to_dict(obj)
