"""The control core: detections and EGM feedback in, setpoints out, on the controller's clock.

The daemon and the lockstep simulator drive the same core: :meth:`ControlCore.on_detection` takes
a detection payload (intake, then the executor's filter and planner) and
:meth:`ControlCore.on_feedback` answers one ``EgmRobot`` with the executor's setpoint for that
packet's controller time, filtered by the safety supervisor against the measured joints.

Clock-free (time is passed in, s). The controller's clock (:mod:`thinkfast.control.egm_clock`)
says which cycle each packet belongs to: the same cycle gets the same setpoint again, a gap is
answered one cycle on (:attr:`ControlCore.held` counts the cycles held) and the executor plans
again from there (:meth:`Executor.resync`), and a first packet or one after a silence restarts
the stream from the measured feedback. Every plan starts from the commanded state. Without
motors on and EGM motion running the core commands the measured position (*standby*); faults
stop the arm smoothly, then recover, or latch after ``max_faults``.

The reply policy case by case, the controller state and the faults: docs/DESIGN.md, "The
control core", "Replies on the controller's clock".
"""

from __future__ import annotations

import collections
import math
from typing import NamedTuple

import numpy as np

from thinkfast.control.egm_clock import ClockTick, ControllerClock
from thinkfast.control.feedback_rate import FeedbackRate, span_before
from thinkfast.control.intake import Intake
from thinkfast.control.link import Feedback
from thinkfast.control.modes import FAULT, IDLE
from thinkfast.control.motion import Motion
from thinkfast.control.outcome import (
    CoreState,
    DetectionOutcome,
    ThrowFigures,
    figures_of,
    outcome_of,
    state_of,
)
from thinkfast.control.safety import KEPT_BRAKES, Ahead, SafetyConfig, SafetySupervisor

DEFER_MAX = 3  # packets left unanswered after a silence in motion, waiting for a velocity
# rad/s: a commanded velocity below this on every joint is rest (a numerical residue: the
# wrist's Ruckig standstill keeps a velocity of ~1e-20 rad/s that never decays)
REST_SPEED = 1e-9


FAULT_REASONS = ("deviation", "nonfinite")  # brakes that count as faults (recovered, latched)


class Reply(NamedTuple):
    """One reply: ``q`` [rad], ``qd`` [rad/s] (n_joints,), the ``mode`` to mirror, the tick."""

    q: np.ndarray
    qd: np.ndarray
    mode: str
    tick: ClockTick


class ControlCore:
    """Executor + supervisor on the controller's clock, with fault recovery (module doc).

    Args:
        executor: the motion source (:class:`~thinkfast.control.motion.Motion`): the daemon's
            executor (detections, queries) or the reply process's plan follower.
        supervisor: the safety supervisor (the last stage before the wire).
        cfg: supervisor and recovery parameters.
        on_event: ``on_event(t, kind, detail)`` for things worth logging and recording.
        shadow: plan a virtual arm, command the position measured at the start (module doc).
        intake: detection intake for :meth:`on_detection` (None: detections are not taken).
    """

    def __init__(
        self,
        executor: Motion,
        supervisor: SafetySupervisor,
        cfg: SafetyConfig,
        on_event=lambda t, kind, detail: None,
        shadow: bool = False,
        intake: Intake | None = None,
    ):
        self.ex, self.sup, self.cfg, self.on_event = executor, supervisor, cfg, on_event
        self.intake = intake
        self.planner_errors = 0  # executor.on_detection failures (each brakes)
        self.shadow = shadow
        self.standby = False  # the controller does not follow references (module doc)
        self.standby_replies = 0
        self.hold_q: np.ndarray | None = None  # shadow: the position sent [rad] (n_joints,)
        self._last_rx = -math.inf  # receive time of the last packet (shadow) [s]
        self.clock = ControllerClock(cfg.dt, cfg.resync_after)
        self.last: Reply | None = None
        self.repeats = 0  # duplicate or stale packets answered with the same setpoint
        self.resyncs = 0  # restarts from the measured feedback (first packet excluded)
        self.deferred = 0  # packets left unanswered after a silence (measuring the velocity)
        self.held = 0  # cycles the controller kept the last reference (unanswered packets)
        self.catch_ups = 0  # replies that moved on from a held reference (replanned from it)
        self._repeated_late = False  # the last reply repeated a late one
        self._waiting = -1  # packets deferred since the silence being resynchronised (-1: none)
        self.faults: collections.deque[float] = collections.deque()  # times, within the window
        self.fault_count = 0
        self.latched = False
        self.rate = FeedbackRate(cfg.dt)  # velocity and rest measured from the feedback
        self._unmeasured: tuple | None = None  # (tick, q, span) to measure (settle)
        self._prepared: Prepared | None = None  # the next cycle's reply, computed ahead
        self.errors = 0  # executor.setpoint failures (each brakes)
        self.last_error: Exception | None = None

    # ------------------------------------------------------------------ queries
    @property
    def measured(self) -> tuple[float, np.ndarray] | None:
        """(controller time [s], joints [rad] (n_joints,)) of the last feedback, None before
        any."""
        self.settle()
        return self.rate.fb

    @property
    def prepared(self) -> Ahead | None:
        """The reply prepared for the next cycle (:meth:`prepare`), filtered ahead; None when
        nothing is (or its setpoint failed)."""
        p = self._prepared
        return None if p is None or p.t != self.t_next else p.ahead

    @property
    def t_next(self) -> float:
        """Controller time of the next cycle [s] (-inf before the first packet)."""
        return self.clock.t + self.cfg.dt

    def at_rest(self) -> bool:
        """Nothing moves and nothing will without a new detection (the time base may move):
        the executor idle and every commanded velocity below :data:`REST_SPEED` (a shift of
        the time base by ``lag`` [s] then moves no setpoint by more than ``REST_SPEED * lag``),
        not braking."""
        sup = self.sup
        if self.ex.mode != IDLE or sup.braking:
            return False
        return max(map(abs, sup.qd.tolist())) < REST_SPEED

    def state(self) -> CoreState:
        """The executor's part of the status (:class:`~thinkfast.control.outcome.CoreState`)."""
        return state_of(self.ex)

    def figures(self) -> ThrowFigures:
        """Decisions, start and hedges of the throws (the simulators' judgement)."""
        return figures_of(self.ex)

    @property
    def busy(self) -> bool:
        """A throw episode is under way (the executor is not idle)."""
        return self.ex.mode != IDLE

    @property
    def stage(self) -> tuple:
        """The hedge stage of the throw (``STAGE_KEYS``' values): a ``stage`` event on change."""
        ex = self.ex
        return (ex.stage, ex.hedge_end, ex.hedges, ex.throw_end)

    @property
    def away(self) -> bool:
        """The arm is held away from home, balls ignored, until :meth:`go_home`."""
        return self.ex.away

    def go_home(self, t: float) -> None:
        """Leave a hold away from home at ``t`` [s]: return home within the return limits."""
        self.ex.go_home(t)

    def mode(self) -> str:
        """Executor mode, ``brake`` while braking, ``fault`` while latched."""
        if self.latched:
            return FAULT
        return "brake" if self.sup.braking else self.ex.mode

    # ------------------------------------------------------------------ cycle
    def prepare(self) -> None:
        """Compute the next cycle's reply ahead: the executor's setpoint for the controller
        time of the next cycle, filtered by the supervisor (:meth:`SafetySupervisor.
        filter_ahead`). The reply to that cycle's packet then only checks the feedback and
        commits it, bit for bit what it would have computed; anything else since (a detection,
        a brake, a resync, a skipped cycle) voids it. Nothing is computed when the reply for
        that cycle is ready already, or before the first packet. A failing setpoint prepares
        nothing (the reply asks again, counts it and brakes)."""
        t = self.t_next
        if self.last is None or (self._prepared is not None and self._prepared.t == t):
            return
        self.invalidate()  # one for an earlier cycle (packets left unanswered since)
        try:
            q_req, qd_req = self.ex.setpoint(t)
        except Exception:
            self._prepared = Prepared(t, None)
            return
        self._prepared = Prepared(t, self.sup.filter_ahead(q_req, qd_req))

    def invalidate(self) -> None:
        """The plan is about to change (call it first): a prepared setpoint is void, and an
        executor that can (``retract()``: the reply process's follower) forgets having been
        asked for it, so that preparing ahead changes no reply."""
        if self._prepared is not None:
            self._prepared = None
            self.ex.retract()

    def on_detection(
        self, payload: bytes, now: float | None, t_plan: float, crossing: bool = False
    ) -> DetectionOutcome:
        """One detection ``payload`` received at ``now`` [s] (None: no clock checks, lockstep):
        validated by the intake and, when accepted, fused and planned on by the executor, the
        plan taking effect at ``t_plan`` (the controller time of the next cycle). Returns what
        happened (:class:`~thinkfast.control.outcome.DetectionOutcome`; its crossing only with
        ``crossing``). Never raises: a planner failure is counted in ``planner_errors``
        (``last_error``) and brakes."""
        ex, was = self.ex, self.ex.mode
        det = self.intake.take(payload, now)
        if det is None:
            return outcome_of(ex, None, self.intake.last_drop, was, None, False)
        self.invalidate()  # the plan changes: prepare again
        error = None
        try:
            refused = ex.on_detection(t_plan, det.stamp, det.position, det.camera)
            if refused is not None:
                self.intake.reject_accepted(refused)
                return outcome_of(ex, None, (refused, ""), was, None, False)
        except Exception as exc:  # a planner bug must not stop the EGM loop: stop the arm
            self.planner_errors += 1
            self.last_error = error = exc
            self.brake("nonfinite")
        return outcome_of(ex, det, None, was, error, crossing)

    def on_feedback(
        self, fb: Feedback, now: float, before: Feedback | None = None, late: bool = False
    ) -> Reply | None:
        """The reply to one controller feedback ``fb`` (:class:`~thinkfast.control.link.
        Feedback`: joints [rad], the controller's clock and cycle count, readiness) received at
        ``now`` [s], or None: leave it unanswered (after a silence in motion, until three
        packets measure the velocity; counted in ``deferred``). ``before``: the feedback just
        before it when that one was superseded unanswered (it measures the velocity after a
        stall of this host). ``late``: the previous reply reached the controller a cycle late
        (this feedback arrived before it left; docs/DESIGN.md, The control core). Not ``ready``:
        the reply is the measured position. Never raises: a failing ``executor.setpoint`` is
        counted in ``errors`` and brakes.

        In shadow mode the reply's ``q``/``qd`` are the virtual arm's; the caller sends
        :attr:`hold_q` at rest instead."""
        tm_ms, q_meas, seqno, ready = fb.t_ms, fb.q, fb.cycle, fb.ready
        if self._unmeasured is not None:
            self.settle()
        if not (ready or self.shadow):
            return self._standby(tm_ms, q_meas, now, seqno)
        if self.shadow:  # hold where the arm stands when the stream (re)starts
            silent = now - self._last_rx > self.cfg.resync_after
            if not ready or silent or self.hold_q is None:
                self.hold_q = np.array(q_meas, dtype=float)
            self._last_rx = now
        return self._on_feedback(tm_ms, q_meas, now, before, seqno, late)

    def _on_feedback(self, tm_ms, q_meas, now, before, seqno, late=False) -> Reply | None:
        tick = self.clock.tick(tm_ms, now, self.at_rest(), seqno)
        if self.standby:  # the controller follows references again: restart from the arm
            self.standby = False
            self._waiting = -1
            self.on_event(tick.t, "controller_ready", {"q": np.round(q_meas, 4).tolist()})
            return self._restart(tick._replace(resync=True), q_meas, np.zeros(self.sup.q.size))
        if tick.repeat and self._waiting >= 0:
            self.deferred += 1  # the same packet again: still nothing measured
            return None
        if tick.repeat and self.last is not None:
            self.repeats += 1
            return self.last._replace(tick=tick)
        span = span_before(tm_ms, seqno, before, self.cfg.dt)
        if not (tick.resync or self.last is None or self._waiting >= 0):
            return self._on_cycle(tick, q_meas, span, late)
        qd_meas = self.rate.measure(tick, q_meas, span)
        if tick.resync and self.last is not None and not self.latched and not self.at_rest():
            self._waiting = max(self._waiting, 0)  # a silence in motion: measure the velocity;
            self.rate.track.clear()  # another silence while waiting does not restart the count
        if self._waiting >= 0:
            qd_end = self.rate.track_velocity(tick, q_meas, qd_meas)
            if qd_end is None and self._waiting < DEFER_MAX:
                self._waiting += 1
                self.deferred += 1
                return None
            self._waiting = -1
            return self._restart(tick, q_meas, qd_end if qd_end is not None else qd_meas)
        return self._restart(tick, q_meas, qd_meas)

    def _on_cycle(self, tick: ClockTick, q_meas, span, late: bool) -> Reply:
        """The reply to a packet a cycle or more on, in a running stream: the prepared one when
        it applies. The feedback's velocity is measured after it (:meth:`settle`): nothing
        here needs it but a brake's recovery."""
        self._unmeasured = (tick, q_meas, span)
        prepared = self._prepared
        steps = max(1, round(tick.elapsed / self.cfg.dt))
        h = tick.elapsed / steps
        ahead = prepared.ahead if prepared is not None and prepared.t == tick.t else None
        if ahead is None or steps > 1 or (late and not self._repeated_late):
            self.invalidate()  # not used: the setpoint is asked afresh
        self._prepared = None
        if late and not self._repeated_late:  # the controller takes this reply where it kept
            self._repeated_late = True  # the one before the last (once: a lasting lag is steady)
            self._catch_up(tick.t, steps)
            self.last = Reply(self.sup.q, self.sup.qd, self.mode(), tick)
            return self.last
        self._repeated_late = late  # still late: the controller takes one reply per cycle
        if steps > 1:
            self._catch_up(tick.t - h, steps - 1)
        was_braking = self.sup.braking
        q_fb = None if self.shadow else q_meas
        if ahead is not None and steps == 1:
            cmd = self.sup.step_ahead(ahead, q_meas=q_fb, dt=h)
        else:
            cmd = self.sup.step(*self._plan(tick.t), q_meas=q_fb, dt=h)
        if cmd.braking and not was_braking:
            dev = self.sup.deviation(q_meas)
            self.on_event(
                tick.t,
                "brake",
                {
                    "reason": self.sup.brake_reason,
                    "mode": self.ex.mode,
                    "deviation": None if dev is None else np.round(dev, 4).tolist(),
                },
            )
        if cmd.kinds and not cmd.braking:  # the plan goes on from what was commanded
            self.ex.resync(cmd.q, cmd.qd, self.sup.qdd, tick.t)
        if cmd.braking:
            self.settle()
            self._while_braking(tick.t, q_meas)
        self.last = Reply(self.sup.q, self.sup.qd, self.mode(), tick)
        return self.last

    def settle(self) -> None:
        """Measure the last feedback's velocity if its reply left that for after it (the rest
        the recovery waits for, :class:`FeedbackRate`): call it between packets; every call
        that needs it makes it first."""
        if self._unmeasured is not None:
            args, self._unmeasured = self._unmeasured, None
            self.rate.measure(*args)

    def brake(self, reason: str) -> None:
        """Latch a smooth stop (``signal``, or ``nonfinite`` for a planner failure)."""
        self.sup.request_brake(reason)

    # ------------------------------------------------------------------ internals
    def _plan(self, t: float):
        """The executor's setpoint at ``t``, or (None, None) when it fails (the supervisor
        brakes on it)."""
        try:
            return self.ex.setpoint(t)
        except Exception as exc:  # a planner bug must cost a smooth stop, never a reply
            self.errors += 1
            self.last_error = exc
            return None, None

    # ------------------------------------------------------------------ restarts and faults
    def _standby(self, tm_ms, q_meas, now: float, seqno=None) -> Reply:
        """The controller does not follow references: command the measured position at rest
        and keep the planner's state on the arm (module doc)."""
        tick = self.clock.tick(tm_ms, now, True, seqno)
        self.invalidate()
        q = np.array(q_meas, dtype=float)
        first = self.last is None
        self.sup.reset(q, keep=KEPT_BRAKES)  # a planner lost stays lost, a stop asked stays
        if first:
            self.ex.start_from(np.array(self.sup.q), tick.t)
        if not self.standby:
            self.standby = True
            self.on_event(tick.t, "controller_standby", {"q": np.round(q, 4).tolist()})
        self.standby_replies += 1
        self.rate.fb = (tick.t, q)
        self.last = Reply(self.sup.q, np.zeros(self.sup.q.size), "standby", tick)
        return self.last

    def _catch_up(self, t_from: float, held: int) -> None:
        """The controller kept the last reference for ``held`` cycles: the commanded state is
        still the supervisor's, one cycle before this reply (``t_from`` [s]). The executor
        plans on from it with the same intent (module doc); at rest or while braking nothing
        depends on time."""
        self.held += held
        if self.sup.braking or self.at_rest():
            return
        self.catch_ups += 1
        try:
            a_max = self.sup.limits.a_max  # the extrapolated end may pass the limit by a little
            self.ex.resync(
                self.sup.q, self.sup.qd, np.clip(self.sup.qdd_end, -a_max, a_max), t_from
            )
        except Exception as exc:  # a planner bug must cost a smooth stop, never a reply
            self.errors += 1
            self.last_error = exc
            self.brake("nonfinite")

    def _restart(self, tick: ClockTick, q_meas, qd_meas) -> Reply:
        """First packet or after a silence: command the measured state, plan on from it. A
        brake whose cause lies outside the stream (:data:`KEPT_BRAKES`: a stop signal, a
        planner stalled or lost) stays latched and stops the arm from the measured state (or
        holds it there at rest, once its stop was done)."""
        self.invalidate()
        first = self.last is None
        sup = self.sup
        if sup.braking and sup.stopped and sup.brake_reason in KEPT_BRAKES:
            qd_meas = None  # the stop is done: hold the arm where it is, at rest
        if first:
            self.sup.reset(q_meas, keep=KEPT_BRAKES)
            self.ex.start_from(np.array(self.sup.q), tick.t)
        elif self.latched:
            self.sup.reset(q_meas)
            self.sup.request_brake("deviation")  # latched: hold where the arm stands
            self.ex.hold_fault(np.array(self.sup.q), tick.t)
        elif self.ex.away:  # held away from home: start again from where the arm stands now
            self.sup.reset(q_meas, keep=KEPT_BRAKES)
            self.ex.start_from(np.array(self.sup.q), tick.t)
        elif not self.sup.resync(q_meas, qd_meas, KEPT_BRAKES):
            pass  # unusable measurement: the supervisor brakes from the old state
        else:
            self.resyncs += 1
            self.ex.resync(self.sup.q, self.sup.qd, np.zeros(self.sup.q.size), tick.t)
            self.on_event(tick.t, "resync", {"silence": "restart from the measured feedback"})
        self.last = Reply(self.sup.q, self.sup.qd, self.mode(), tick)
        return self.last

    def _while_braking(self, t: float, q_meas) -> None:
        reason = self.sup.brake_reason
        if reason not in FAULT_REASONS or not self.sup.stopped or self.latched:
            return
        if t - self.rate.rest_since < self.cfg.recover_after:
            return  # the commanded stop is done; wait until the arm stands too
        self.fault_count += 1
        while self.faults and t - self.faults[0] > self.cfg.fault_window:
            self.faults.popleft()
        self.faults.append(t)
        if len(self.faults) >= self.cfg.max_faults:
            self.latched = True
            self.sup.reset(q_meas)
            self.sup.request_brake(reason)  # stays braked (at rest): requests are ignored
            self.ex.hold_fault(np.array(self.sup.q), t)
            self.on_event(t, "fault_latched", {"reason": reason, "faults": len(self.faults)})
            return
        self.sup.reset(q_meas)  # the arm stands: restart from where it is, then go home
        self.ex.recover(np.array(self.sup.q), t)
        self.on_event(t, "recover", {"reason": reason, "faults": len(self.faults)})


class Prepared(NamedTuple):
    """The reply to the next cycle, computed ahead (:meth:`ControlCore.prepare`).

    Attributes:
        t: the controller time [s] of the cycle it is for.
        ahead: the executor's setpoint for ``t``, filtered by the supervisor; None when the
            setpoint failed (the reply asks the executor again).
    """

    t: float
    ahead: Ahead | None
