"""The ``thinkfast-run`` daemon: one thread, EGM first.

The loop waits on the EGM socket; every ``EgmRobot`` of the one controller it serves is answered
at once with the executor's setpoint for that packet's time on the controller's clock, passed
through the safety supervisor (the last stage before the wire); see
:mod:`thinkfast.control.core`. Between two EGM packets (4 ms) it drains the zenoh
detection queue (filter, crossing, values, backup), publishes the mirrored setpoints and the
status. Signals only set a flag: the loop brakes
smoothly while the controller still talks to it, then exits 0.

Nothing may delay a reply, so the other work runs right after one: the first queued detection
is taken at once after a reply, further ones only while, at the cost of the slowest recent one,
they end before the next ``EgmRobot``'s window opens (:mod:`thinkfast.link.cycle`). The
mirrored setpoints and the status go out in the same place, and so do garbage collections
(automatic collection is off while serving; the interpreter's own thresholds decide).

When the window opens, shortly before the next ``EgmRobot`` is due, the reply is prepared: the
executor's setpoint for the time the packet is due, filtered by the supervisor ahead
(:class:`thinkfast.control.core.Prepared`); the reply itself then only decodes, runs the
supervisor's checks on the feedback, and encodes. By default the loop sleeps in ``poll`` (1 ms at
a time) until a packet comes; with ``spin_ahead`` it spins on the socket inside the window (on a
virtual machine Python runs several times slower right after a sleep), and with ``spin_ahead
>= dt`` (busy polling) all the time, at the cost of a whole core. ``cpu`` pins the loop's thread
to one core (and zenoh's threads to the others), ``fifo`` puts it under SCHED_FIFO
(:mod:`thinkfast.link.rt_thread`). docs/BENCHMARKS.md has the figures.
"""

from __future__ import annotations

import collections
import functools
import json
import logging
import math
import os
import select
import signal
import time

import numpy as np

from thinkfast.config import to_dict
from thinkfast.control.assembly import CoreAssembly
from thinkfast.control.config import RunConfig
from thinkfast.control.link import Feedback
from thinkfast.control.modes import STAGE_KEYS
from thinkfast.daemon.home_watch import HomeWatch
from thinkfast.daemon.options import Endpoints, Modes
from thinkfast.daemon.status_text import episode_end, peer_text, status_message, summary
from thinkfast.daemon.zenoh_edge import ZenohIO
from thinkfast.link import gc_rule
from thinkfast.link.cycle import Cycle
from thinkfast.link.registry import LinkSpec, open_link
from thinkfast.link.rt_thread import pin_thread, set_fifo
from thinkfast.record.recorder import Recorder
from thinkfast.record.tables import plane_json
from thinkfast.robot.model import Robot
from thinkfast.tree.action_tree import ActionTree
from thinkfast.tree.file import tree_fingerprint

log = logging.getLogger("thinkfast.run")
STATUS_COST = 0.001  # s set aside for a status message (JSON, timing percentiles)


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
        modes: Modes = Modes(),
        view=None,
    ):
        self.cfg, self.robot, self.planner, self.modes = cfg, robot, planner, modes
        self.view = view  # live view (view/live.DaemonView: Rerun or Foxglove) or None
        self.tree_meta = tree.meta
        self.tree_fingerprint = tree_fingerprint(tree)  # `thinkfast-compile diff` prints it too
        self.cycle, self.cpu, self.fifo = Cycle(cfg.safety.dt, spin_ahead), cpu, fifo
        self.recorder = Recorder(
            endpoints.record,
            {
                "planner": planner,
                "tree_config_sha256": tree.meta.get("config_sha256", ""),
                "tree_fingerprint": self.tree_fingerprint,
                "robot_name": robot.name,
                "robot_toml": str(robot.toml_path),
                "robot_toml_sha256": robot.toml_sha256,
                "urdf_sha256": robot.urdf_sha256,
                "plane": plane_json(robot.placement),  # estimates are in this plane's frame
                "shadow": int(modes.shadow),
                "run_config": json.dumps(to_dict(cfg)),
                "started": time.time(),
            },
        )  # first: a record target that cannot be written stops the start, before serving
        parts = CoreAssembly(tree, robot, cfg)
        # on the wall clock a late solve is dropped; the way home is checked first (--go-home)
        self.executor = parts.executor(planner, realtime=True, home_on_start=False)
        self.runtime_tree = parts.tree  # the tree as the planners see it (the live view's)
        self.plane_x = float(parts.tree.plane_x)  # the plane's distance [m] (status, summary)
        way = functools.partial(parts.executor, "naive")  # plans the way home
        self.home = HomeWatch(robot, modes.go_home, cfg.safety.dt, way, self._event)
        self.limits = parts.limits
        self.control = parts.core(self.executor, self._event, modes.shadow)
        self.supervisor, self.intake = self.control.sup, self.control.intake
        self.controller_state: dict | None = None  # motors, MCI, RAPID as last reported
        self._controller_key: tuple | None = None  # the same three, to compare per reply
        self.planned: tuple[np.ndarray, np.ndarray, str] | None = None  # shadow: virtual arm
        self._was_connected = False
        self.link_text = "EGM" if endpoints.link == "egm" else f"the {endpoints.link} link"
        self.link = self._open_link(endpoints)  # the controller's wire (thinkfast.link)
        if endpoints.ros_domain is None:
            self.zio = ZenohIO(zenoh_conf, endpoints.key_prefix, endpoints.insecure_zenoh)
        else:  # rosbags (the ros extra) only when asked for
            from thinkfast.daemon.ros_edge import RosIO

            self.zio = RosIO(
                zenoh_conf, endpoints.key_prefix, endpoints.ros_domain, endpoints.insecure_zenoh
            )
        self.stop_reason: str | None = None
        self._signal_braked = False  # the signal's brake was logged
        self.last_rx = -math.inf  # receive time of the last served EgmRobot (wall clock)
        self.outbox: list[tuple[float, np.ndarray, np.ndarray, str, np.ndarray]] = []
        self.decision_ms = 0.0
        self.planner_errors = 0
        self.pending: collections.deque[bytes] = collections.deque()  # drained, not yet taken
        self.detection_cost = 0.001  # s, decaying maximum of recent detection handling times
        self.last_throw: dict | None = None  # supervisor interventions in the last throw
        self._throw_mark: tuple[int, int] | None = None  # (ticks, intervened) at its start
        self._stage: tuple = ("", "", 0, "")  # the executor's (stage, hedge_end, hedges, throw_end)
        self._peer = None

    # -------------------------------------------------------------- EGM path
    def _open_link(self, endpoints: Endpoints):
        """The controller link ``endpoints.link`` answering with :meth:`_reply`
        (thinkfast.daemon.planner_process: in the reply process)."""
        spec = LinkSpec(endpoints.egm_bind, endpoints.egm_controller, endpoints.egm_handover,
                        self.cfg.safety.dt)  # fmt: skip
        return open_link(endpoints.link, spec, self._reply)

    def link_where(self) -> str:
        """Where the controller link listens, for the log (``host:port`` for a socket)."""
        address = self.link.address
        return peer_text(address) if isinstance(address, tuple) else str(address)

    def _reply(self, fb: Feedback, before: Feedback | None = None):
        """The setpoint answering the feedback ``fb``, or None to leave it unanswered (after a
        silence in motion, until three packets measure the velocity; docs/DESIGN.md)."""
        now = time.time()
        self.last_rx = now
        if self.stop_reason is not None:
            self._brake_on_signal()
        errors = self.control.errors
        late = self.link.behind  # the last reply reached the controller a cycle late
        r = self.control.on_feedback(fb, now, before, late)
        if fb.state != self._controller_key:
            self._controller_changed(fb, now)  # after the clock took this packet's time
        if self.control.errors != errors:
            self._planner_error("setpoint", self.control.last_error)
        if r is None:
            return None
        self._watch_throw(r.tick.t)
        self._watch_stage(r.tick.t)
        q, qd, mode = r.q, r.qd, r.mode
        q_rec, qd_rec = q, qd  # the record keeps the commanded motion (in shadow: the plan)
        if self.modes.shadow:  # the plan is shown, the arm holds (egm_control)
            self.planned = (q, qd, mode)
            q, qd, mode = self.control.hold_q, np.zeros(self.robot.n_joints), "shadow"
        self.outbox.append((r.tick.t, q, qd, mode, fb.q))
        cycle = -1 if fb.cycle is None else fb.cycle
        self.recorder.egm(now, cycle, fb.q, q_rec, qd_rec, self.supervisor.braking)
        return q, qd

    def _brake_on_signal(self) -> None:
        """SIGINT/SIGTERM while the controller talks: brake smoothly; the first time, a log line
        and a record event saying what was going on."""
        if not self._signal_braked:
            self._signal_braked = True
            st = self.control.state()
            self._event(
                self.control.clock.t,
                "brake",
                {"reason": "signal", "signal": self.stop_reason, "mode": st.mode,
                 "throws": st.throws},
            )  # fmt: skip
        self.control.brake("signal")

    def _controller_changed(self, fb: Feedback, now: float) -> None:
        """The controller reports another state (EGM: motors, MCI, RAPID): status and a log
        line, stamped with this packet's controller time (its receive time ``now`` [s] before
        the controller's clock has started)."""
        self._controller_key = fb.state
        self.controller_state = {**dict(fb.state), "ready": fb.ready}
        t = self.control.clock.t
        self._event(t if math.isfinite(t) else now, "controller_state", self.controller_state)

    def _planner_error(self, where: str, exc: BaseException | None) -> None:
        self.planner_errors += 1
        if self.planner_errors == 1 or self.planner_errors % 100 == 0:
            log.error("%s error %d: braking", where, self.planner_errors, exc_info=exc)

    def _event(self, t: float, kind: str, detail: dict) -> None:
        """Something worth a log line and a record row (from the control core or here)."""
        log.info("%s %s", kind, json.dumps(detail), extra={"event": kind, "detail": detail})
        self.recorder.event(t, kind, detail)

    def _watch_throw(self, t: float) -> None:
        """Count the supervisor's interventions per throw (status and record)."""
        sup, busy = self.supervisor, self.control.busy
        if busy and self._throw_mark is None:
            self._throw_mark = (sup.ticks, sup.intervened)
        elif not busy and self._throw_mark is not None:
            ticks0, intervened0 = self._throw_mark
            self._throw_mark = None
            self.last_throw = {
                "ticks": sup.ticks - ticks0,
                "intervened": sup.intervened - intervened0,
            }
            kind, detail = episode_end(self.control.state())  # throw_end, or never confirmed
            self._event(t, kind, {**detail, **self.last_throw})

    def _watch_stage(self, t: float) -> None:
        """A ``stage`` event (log and record) whenever the executor's stage of commitment
        changes: a hedge begins (``hedge``), ends (``hedge_end``: why), the commit takes over or
        a throw's motion ends (``throw_end``: why, ``retracted`` for a feint taken for a throw)."""
        stage = self.control.stage
        if stage != self._stage:
            self._stage = stage
            self._event(t, "stage", dict(zip(STAGE_KEYS, stage, strict=True)))

    # -------------------------------------------------------------- main loop
    def run(self) -> int:
        """Serve until SIGINT/SIGTERM, then brake and return 0."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)
        poller = select.poll()
        poller.register(self.link.fileno(), select.POLLIN)
        gc_rule.hold()  # collections run after replies (_collect_garbage), never inside one
        status_period = 1.0 / self.cfg.status_rate
        next_status = time.time()
        spin = "always" if self.cycle.busy else f"{1e3 * self.cycle.spin_ahead:g} ms ahead"
        log.info(
            "serving %s on %s, planner %s, spinning %s", self.link_text, self.link_where(),
            self.planner,
            spin if self.cycle.spin_ahead > 0 else "never",
        )  # fmt: skip
        cycle = self.cycle
        try:
            if self.cpu is not None:  # here: zenoh's threads are running (they move away)
                others = os.sched_getaffinity(0) - {self.cpu}
                pin_thread(self.cpu)
                self.recorder.move_writer(others)
            if self.fifo is not None:  # this thread only
                set_fifo(self.fifo)
            self._event(time.time(), "start", self.summary())
            while True:
                since = time.time() - self.last_rx
                if cycle.in_window(since):  # the next reply ahead, once per cycle
                    self.control.prepare()  # (an EGM codec warm-up here: within noise, dropped)
                wait_ms = cycle.wait_ms(since)
                replied = bool(poller.poll(wait_ms)) and self.link.poll() > 0  # replies at once
                self._flush_outbox()
                self._watch_peer()
                self._take_detections(replied)
                self.home.service(self.control, self._time_left, self._plan_time)
                now = time.time()
                if now >= next_status and self._time_left(now) > STATUS_COST:
                    msg = self.status(now)
                    self.zio.publish_status(msg)
                    if self.view is not None:  # a reference: drawn in the view's own steps
                        self.view.on_status(now, msg)
                    next_status = now + status_period
                if self.view is not None:  # a job only when its measured cost fits
                    self.view.service(now, self.last_rx, self.control, self._time_left(now))
                self._collect_garbage(now)
                if self._time_left(now) > 0.0005:
                    self.recorder.service()  # hands a batch of rows to the writer process
                if self.stop_reason is not None and self._may_exit(now):
                    break
        finally:
            gc_rule.release()
            self.zio.publish_status({**self.status(time.time()), "exiting": True})
            self.recorder.close()
            self.link.close()
            self.zio.close()
            if self.view is not None:
                self.view.close()  # logs what is still queued, flushes (a saved file ends)
        log.info("stopped (%s)", self.stop_reason)
        return 0

    def _on_signal(self, signum, _frame) -> None:
        self.stop_reason = signal.Signals(signum).name

    def _may_exit(self, now: float) -> bool:
        return not self.connected(now) or (self.supervisor.braking and self.supervisor.stopped)

    def connected(self, now: float) -> bool:
        """The controller talks to the daemon (a packet within the last 0.1 s)."""
        return now - self.last_rx < max(0.1, 5.0 * self.cfg.safety.resync_after)

    def _watch_peer(self) -> None:
        if self.link.peer != self._peer:
            self._peer = self.link.peer
            self._event(self.control.clock.t, "egm_peer", {"peer": peer_text(self._peer)})
        connected = self.connected(time.time())
        if connected != self._was_connected:
            self._was_connected = connected
            kind = "egm_connected" if connected else "egm_lost"
            self._event(self.control.clock.t, kind, {"peer": peer_text(self.link.peer)})

    def _flush_outbox(self) -> None:
        for stamp, q, qd, mode, q_meas in self.outbox:
            self.zio.publish_setpoint(stamp, q, qd, mode, q_meas)
        self.outbox.clear()

    def _time_left(self, now: float) -> float:
        """Seconds of work that still end before the next EgmRobot's window opens."""
        return self.cycle.time_left(now - self.last_rx)

    def _collect_garbage(self, now: float) -> None:
        """Collect as the interpreter would (same thresholds), where it cannot delay a reply."""
        if self._time_left(now) >= 0.001:
            gc_rule.collect_due()

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

    def _plan_time(self, now: float) -> float:
        """When a plan made now takes effect: the controller time of the next cycle (plans live
        on the controller's clock; one starting later than the cycle it is first sampled at
        would jump), or now when the controller is silent."""
        return self.control.t_next if self.connected(now) else now

    def _take(self, payload: bytes, now: float) -> None:
        """One detection payload received at ``now``: recorded raw, then the core's outcome
        (intake, filter, planner) recorded, shown and logged."""
        self.recorder.raw(now, payload)
        t0 = time.perf_counter()
        out = self.control.on_detection(payload, now, self._plan_time(now), self.recorder.enabled)
        if self.view is not None:  # queued only: logged in idle time (service)
            self.view.on_detection(now, payload, out)
        det = out.detection
        if det is None:
            self._log_drop(out.dropped)
            return
        self.recorder.detection(now, det.stamp, det.position, det.seq)
        if out.error is not None:
            self._planner_error("planner", out.error)
            return
        self.decision_ms = 1e3 * (time.perf_counter() - t0)
        if out.crossing is not None:  # computed for the record only
            self.recorder.belief(now, out.belief, out.crossing)
        d = out.decision
        if d is not None:
            self.recorder.decision(now, d.mode, d.node, d.value, d.goal)
        if out.started:
            value = None if d is None else round(d.value, 3)
            self._event(self.control.clock.t, "throw_start", {"throw": out.throw, "value": value})

    def _log_drop(self, reason: tuple[str, str] | None) -> None:
        """A dropped detection: log the first of each reason, then at 10, 100, 1000, ..."""
        if reason is None:
            return
        n = self.intake.dropped(reason[0])
        if n == 1 or math.log10(n).is_integer():
            log.warning("detection dropped (%s: %s), %d so far for this reason", *reason, n)

    def status(self, now: float) -> dict:
        """The status message (docs/INTERFACES.md: at least stamp and state)."""
        return status_message(self, now)

    def summary(self) -> dict:
        """What the daemon runs with (logged at start-up)."""
        return summary(self)
