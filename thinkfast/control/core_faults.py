"""The control core's restarts, standby, catch-up and faults: the policy of
:class:`~thinkfast.control.core.ControlCore` after a silence, while the controller does not
follow references, after cycles the controller held, and on a fault brake (described in the
module doc of :mod:`thinkfast.control.core`). Clock-free, like the core.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.control.egm_clock import ClockTick
from thinkfast.control.safety import KEPT_BRAKES

FAULT_REASONS = ("deviation", "nonfinite")


class Reply(NamedTuple):
    """One reply: ``q`` [rad], ``qd`` [rad/s] (n_joints,), the ``mode`` to mirror, the tick."""

    q: np.ndarray
    qd: np.ndarray
    mode: str
    tick: ClockTick


class FaultPolicy:
    """The part of :class:`~thinkfast.control.core.ControlCore` that restarts the stream and
    handles faults (module doc); it works on the core's state (a mixin)."""

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
