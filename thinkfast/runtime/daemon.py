"""The ``thinkfast-run`` daemon: one thread, EGM first.

The loop waits on the EGM socket; every ``EgmRobot`` is answered at once with the executor's
setpoint for now, passed through the safety supervisor (the last stage before the wire). Between
two EGM packets (4 ms) it drains the zenoh detection queue (filter, crossing, values, backup),
publishes the mirrored setpoints and the status. Signals only set a flag: the loop brakes
smoothly while the controller still talks to it, then exits 0.
"""

from __future__ import annotations

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
from thinkfast.runtime.egm_server import EgmServer
from thinkfast.runtime.executor import FAULT, IDLE, Executor
from thinkfast.runtime.intake import Intake
from thinkfast.runtime.planner import RuntimeTree
from thinkfast.runtime.recorder import Recorder
from thinkfast.runtime.safety import SafetySupervisor, make_limits
from thinkfast.runtime.zenoh_io import ZenohIO

log = logging.getLogger("thinkfast.run")
BALL_RADIUS = 0.0335  # m, tennis ball (FACTS.md); counts towards the blocking radius


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
    ):
        self.cfg, self.robot, self.planner = cfg, robot, planner
        rt = RuntimeTree(tree, cfg.value, robot.shield_radius + BALL_RADIUS)
        self.executor = Executor(rt, robot, cfg, planner)
        self.limits = make_limits(
            robot.q_lower,
            robot.q_upper,
            robot.v_max,
            robot.a_max,
            robot.j_max,
            cfg.safety.position_margin,
        )
        self.supervisor = SafetySupervisor(self.limits, cfg.safety, robot.home)
        self.intake = Intake(cfg.camera, cfg.detections)
        self.egm = EgmServer(endpoints.egm_bind, self._reply, endpoints.egm_controller)
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
        q_req, qd_req = self.executor.setpoint(now)
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
        status_period = 1.0 / self.cfg.status_rate
        next_status = time.time()
        log.info("serving EGM on %s:%d, planner %s", *self.egm.address, self.planner)
        try:
            while True:
                poller.poll(2)  # ms; EGM packets come every 4 ms
                self.egm.poll(16)
                self._flush_outbox()
                self._take_detections()
                now = time.time()
                if now >= next_status:
                    self.zio.publish_status(self.status(now))
                    next_status = now + status_period
                if self.stop_reason is not None and self._may_exit(now):
                    break
        finally:
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

    def _take_detections(self) -> None:
        for payload in self.zio.drain():
            now = time.time()
            self.recorder.raw(now, payload)
            det = self.intake.take(payload, now)
            if det is None:
                continue
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
                continue
            self.decision_ms = 1e3 * (time.perf_counter() - t0)
            if ex.belief.n_meas >= 2:
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
        }


def _plain(obj):
    from thinkfast.config import to_dict

    return to_dict(obj)
