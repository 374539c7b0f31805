"""Safety supervisor: the last stage before the wire, independent of the planner.

Every tick (the EGM cycle, ``SafetyConfig.dt``) it takes the planner's requested ``(q, qd)`` and
the previous *commanded* state and returns a command that is inside the position, velocity and
acceleration limits, finite and recoverable (the admissibility kernels and their invariant:
:mod:`thinkfast.control.safety_limits`). On a stop signal, a feedback deviation or a non-finite
request it latches a brake and drives every joint to rest along a jerk-limited stop
(:mod:`thinkfast.control.safety_brake`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.control.safety_brake import JerkLimitedStop, brake_velocity
from thinkfast.control.safety_limits import (
    CLAMP_KINDS,
    SafetyError,
    SafetyLimits,
    TickConstants,
    any_true,
    beyond_envelope,
    filter_tick,
    finite_vector,
    limit_step,
)
from thinkfast.control.safety_limits import robot_limits as robot_limits  # the daemon's import

# planner_stale, planner_lost: the reply process had no word from its planner process in time,
# or lost it (thinkfast.reply.process)
BRAKE_REASONS = ("signal", "deviation", "nonfinite", "planner_stale", "planner_lost")
# brakes whose cause lies outside the EGM stream: a restart of the stream (a silence, standby)
# does not remove them (thinkfast.control.core)
KEPT_BRAKES = ("signal", "planner_stale", "planner_lost")
KINDS = CLAMP_KINDS + tuple(f"brake_{r}" for r in BRAKE_REASONS) + ("init_clamped", "resync")


@dataclasses.dataclass(frozen=True)
class SafetyConfig:
    """Supervisor parameters (joint limits come from the robot model)."""

    dt: float = spec(0.004, doc="tick period (EGM cycle)", unit="s", lo=0.0, lo_open=True)
    position_margin: float = spec(
        0.035, doc="commands stay this far inside the URDF position limits", unit="rad", lo=0.0
    )
    tracking_lag: float = spec(
        0.2,
        doc="ASSUMED longest lag of the arm behind its command (transport, filter and servo "
        "lag; calibrate from logged EGM feedback): the feedback must lie within what was "
        "commanded during this window",
        unit="s",
        lo=0.0,
        hi=2.0,
    )
    max_deviation: float = spec(
        0.1,
        doc="brake when a joint's feedback lies this far outside the range it was commanded "
        "over the last tracking_lag (overshoot of a soft servo, quantisation)",
        unit="rad",
        lo=0.0,
        lo_open=True,
    )
    servo_time_constant: float = spec(
        0.05,
        doc="ASSUMED settling time of the arm's servo: a following arm may overshoot the "
        "commanded range by up to this times the largest commanded speed of the window "
        "(calibrate from logged EGM feedback)",
        unit="s",
        lo=0.0,
        hi=1.0,
    )
    resync_after: float = spec(
        0.02,
        doc="an EGM silence longer than this restarts the setpoint stream from the measured "
        "feedback",
        unit="s",
        lo=0.0,
        lo_open=True,
    )
    recover_after: float = spec(
        0.2,
        doc="after a fault brake, restart (and return home) once the measured arm has been at "
        "rest this long",
        unit="s",
        lo=0.0,
    )
    planner_timeout: float = spec(
        0.25,
        doc="with the reply loop in its own process (--reply-process): a plan whose planner "
        "has given no word for this long is replaced by a smooth stop (brake planner_stale) "
        "until the planner speaks again",
        unit="s",
        lo=0.0,
        lo_open=True,
    )
    max_faults: int = spec(
        3, doc="this many faults within fault_window latch fault until restarted", lo=1
    )
    fault_window: float = spec(
        60.0, doc="window for counting faults towards max_faults", unit="s", lo=0.0, lo_open=True
    )


class SafeCommand(NamedTuple):
    """The supervisor's output for one tick.

    Attributes:
        q: commanded joint angles [rad], shape (n,), finite, inside the limits.
        qd: commanded joint velocities [rad/s], shape (n,), finite.
        braking: a brake is latched (requests are ignored until :meth:`SafetySupervisor.release`).
        stopped: braking and every velocity is zero.
        kinds: interventions made this tick (entries of :data:`KINDS`).
    """

    q: np.ndarray
    qd: np.ndarray
    braking: bool
    stopped: bool
    kinds: tuple[str, ...]


class Ahead(NamedTuple):
    """A request filtered ahead of its tick (:meth:`SafetySupervisor.filter_ahead`).

    Attributes:
        q_req: the request [rad], as it was given.
        qd_req: the request [rad/s], as it was given.
        state: the supervisor's state it was filtered from (:attr:`SafetySupervisor.state`).
        result: ``(q, qd, kinds)`` of :func:`filter_step`, or None (a request that is not
            finite: :meth:`SafetySupervisor.step_ahead` brakes as :meth:`SafetySupervisor.step`).
        bounds: the feedback's envelope from that state, ``(hi, lo, overshoot)`` (n floats each:
            :func:`~thinkfast.control.safety_limits.beyond_envelope`), None without a result.
        qdd: the acceleration [rad/s^2] (n,) of the result over a nominal tick, None without.
    """

    q_req: object
    qd_req: object
    state: int
    result: tuple | None
    bounds: tuple | None = None
    qdd: np.ndarray | None = None


class SafetySupervisor:
    """Stateful wrapper of :func:`filter_step` and :func:`brake_velocity`, one call per tick.

    Besides the limits it watches the feedback: the arm lags its command (transport, filters,
    servo), so a joint's measured position must lie within the range of what was commanded
    over the last ``tracking_lag``, give or take ``max_deviation``; an arm outside that envelope
    has stopped following (or reports nonsense) and the supervisor brakes.

    Args:
        limits: joint limits (margin already applied, see :func:`make_limits`).
        config: tick period and trigger thresholds.
        q0: starting command [rad], normally the measured joint angles; clipped into the limits
            (counted as ``init_clamped``).
    """

    def __init__(self, limits: SafetyLimits, config: SafetyConfig, q0):
        self.limits = limits
        self.config = config
        self.counts = dict.fromkeys(KINDS, 0)
        self.ticks = 0  # ticks stepped
        self.state = 0  # counts changes of the commanded state (steps, resets): see Ahead
        self.intervened = 0  # ticks whose request was changed (clamped) or braked
        self._k = TickConstants.of(limits, config.dt)
        self._window = max(1, math.ceil(config.tracking_lag / config.dt - 1e-9)) + 1
        self.brake_reason: str | None = None
        self.reset(q0)

    def reset(self, q0, qd0=None, keep: tuple[str, ...] = ()) -> None:
        """Start at ``q0`` [rad] moving at ``qd0`` [rad/s] (default: rest), no brake latched
        but one latched for a reason in ``keep``: it stays latched (not counted again), its
        stop planned afresh from the new state.

        Raises:
            SafetyError: a value is not finite or the shapes are wrong.
        """
        q0 = np.array(q0, dtype=float).reshape(-1)
        n = self.limits.q_min.size
        v0 = np.zeros(n) if qd0 is None else np.array(qd0, dtype=float).reshape(-1)
        if q0.size != n or v0.size != n or not (np.isfinite(q0).all() and np.isfinite(v0).all()):
            raise SafetyError(f"safety supervisor: q0 and qd0 must hold {n} finite values")
        q = np.clip(q0, self.limits.q_min, self.limits.q_max)
        if (q != q0).any():
            self.counts["init_clamped"] += 1
        v = np.clip(v0, -self.limits.v_max, self.limits.v_max)
        q.setflags(write=False)
        v.setflags(write=False)
        kept = self.brake_reason
        self.q, self.qd, self.qdd = q, v, np.zeros(n)
        self._qdd_prev = self.qdd
        self.brake_reason = None
        self._stop: JerkLimitedStop | None = None
        if kept in keep:
            self.brake_reason = kept
            self._stop = JerkLimitedStop.plan(v, self.qdd, self.limits)
        self.state += 1
        self._recent = np.tile(q, (self._window, 1))  # ring of recent commands (envelope)
        self._recent_v = np.tile(v, (self._window, 1))
        self._head = 0

    def resync(self, q_meas, qd_meas=None, keep: tuple[str, ...] = ()) -> bool:
        """Restart from the measured state (after an EGM silence; a brake latched for a reason
        in ``keep`` stays, as in :meth:`reset`): returns False when the measurement is unusable
        (the state is kept and a ``deviation`` brake latched)."""
        try:
            self.reset(q_meas, qd_meas, keep)
        except SafetyError:
            self.request_brake("deviation")
            return False
        self.counts["resync"] += 1
        return True

    @property
    def braking(self) -> bool:
        """A brake is latched."""
        return self.brake_reason is not None

    @property
    def qdd_end(self) -> np.ndarray:
        """Commanded acceleration [rad/s^2] (n,) at the end of the last tick, not its average
        over it (the average of a jerk-limited motion lags by half a tick of jerk)."""
        return self.qdd + 0.5 * (self.qdd - self._qdd_prev)

    @property
    def stopped(self) -> bool:
        """The commanded velocity is zero on every joint."""
        return not any(self.qd.tolist())  # plain floats: ndarray.any() costs more for six

    def request_brake(self, reason: str) -> None:
        """Latch a smooth stop; ``reason`` is one of :data:`BRAKE_REASONS` (first one is kept)."""
        if reason not in BRAKE_REASONS:
            raise ValueError(f"brake reason {reason!r} is not one of {', '.join(BRAKE_REASONS)}")
        if self.brake_reason is None:
            self.brake_reason = reason
            self.counts[f"brake_{reason}"] += 1
            self._stop = JerkLimitedStop.plan(self.qd, self.qdd_end, self.limits)

    def release(self) -> None:
        """Accept requests again (call when stopped and the cause is gone)."""
        self.brake_reason = None
        self._stop = None

    def deviation(self, q_meas) -> np.ndarray | None:
        """Per joint [rad], how far ``q_meas`` lies outside the range commanded over the last
        ``tracking_lag``, less the overshoot a following servo may have at the speeds commanded
        then (``servo_time_constant`` times the largest); None when ``q_meas`` is unusable."""
        q = finite_vector(q_meas, self.q.size)
        if q is None:
            return None
        hi, lo, overshoot = self._envelope()
        outside = np.maximum(np.maximum(q - hi, lo - q), 0.0)
        return np.maximum(outside - overshoot, 0.0)

    def _envelope(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(highest, lowest) command of the window and the overshoot allowed [rad] (n,) each."""
        recent = self._recent
        overshoot = self.config.servo_time_constant * np.abs(self._recent_v).max(axis=0)
        return recent.max(axis=0), recent.min(axis=0), overshoot

    def filter_ahead(self, q_req, qd_req) -> Ahead:
        """Filter the next tick's request ahead of time, to take work out of the tick.

        Pure: no state changes. :meth:`step_ahead` uses the result when the commanded state is
        still the one it was filtered from, the tick is nominal and no brake is latched by then:
        exactly what :meth:`step` would compute (the same :func:`filter_step` from the same
        previous command); otherwise it steps afresh.
        """
        n = self.q.size
        q_r, v_r = finite_vector(q_req, n), finite_vector(qd_req, n)
        if q_r is None or v_r is None:
            return Ahead(q_req, qd_req, self.state, None)
        with np.errstate(over="ignore", invalid="ignore"):  # as in filter_step
            res = filter_tick(self.q, self.qd, q_r, v_r, self.limits, self.config.dt, self._k)
        res.q.setflags(write=False)  # fresh arrays, handed out read-only once committed
        res.qd.setflags(write=False)
        bounds = tuple(b.tolist() for b in self._envelope())
        return Ahead(q_req, qd_req, self.state, res, bounds, (res.qd - self.qd) / self.config.dt)

    def step_ahead(self, ahead: Ahead, q_meas=None, dt: float | None = None) -> SafeCommand:
        """:meth:`step` on the request of ``ahead``, using its filter result when it still
        applies (see :meth:`filter_ahead`). Never raises."""
        usable = ahead.result is not None and ahead.state == self.state
        if not usable or (dt is not None and dt != self.config.dt):
            return self.step(ahead.q_req, ahead.qd_req, q_meas, dt)
        if q_meas is not None and beyond_envelope(q_meas, ahead.bounds, self.config.max_deviation):
            self.request_brake("deviation")  # what _check_feedback decides, in plain floats
        if self.braking:
            return self.step(ahead.q_req, ahead.qd_req)
        q, v, kinds = ahead.result
        return self._commit(q, v, kinds, self.config.dt, ahead.qdd)

    def step(self, q_req, qd_req, q_meas=None, dt: float | None = None) -> SafeCommand:
        """Advance one tick. Never raises; whatever the inputs the output is admissible.

        Args:
            q_req: requested joint angles [rad], shape (n,) (anything: checked here).
            qd_req: requested joint velocities [rad/s], shape (n,).
            q_meas: latest measured joint angles [rad], shape (n,), or None; one outside the
                envelope of recent commands by more than ``max_deviation`` (or a non-finite
                value) brakes.
            dt: length of this tick [s] when it is not exactly the nominal ``config.dt`` (the
                controller's clock says how much time passed); within a small fraction of it
                (the braking-room invariant is kept for the nominal tick: step longer gaps as
                several ticks).
        """
        cfg, lim, n = self.config, self.limits, self.q.size
        kinds: tuple[str, ...] = ()
        self._check_feedback(q_meas)
        nominal = dt is None or dt == cfg.dt
        k = self._k if nominal else TickConstants.of(lim, dt)
        h = cfg.dt if nominal else dt
        q_r, v_r = finite_vector(q_req, n), finite_vector(qd_req, n)
        if not self.braking and (q_r is None or v_r is None):
            kinds = ("nonfinite",)
            self.request_brake("nonfinite")
        if self.braking:
            if self._stop is not None:  # a joint that stood (a limit stopped it) stays,
                stood = (self.qd == 0.0) & ~self._stop.through  # but for one turning round
                v_des = np.where(stood, 0.0, self._stop.next(h))
            else:
                v_des = brake_velocity(self.qd, self.qdd, lim, h)
            q, v = limit_step(self.q, self.qd, v_des, lim, h)
            # rounding in the limit bounds can leave +-1e-13 rad/s of the wrong sign: a stop
            # ends at exactly zero
            v = np.where(np.abs(v) < 1e-9, 0.0, v)
        else:
            with np.errstate(over="ignore", invalid="ignore"):  # as in filter_step
                q, v, kinds = filter_tick(self.q, self.qd, q_r, v_r, lim, h, k)
        return self._commit(q, v, kinds, h)

    def _check_feedback(self, q_meas) -> None:
        """Brake on feedback outside the envelope of recent commands (None: no feedback)."""
        if q_meas is not None:
            dev = self.deviation(q_meas)
            if dev is None or any_true(dev > self.config.max_deviation):
                self.request_brake("deviation")

    def _commit(
        self, q: np.ndarray, v: np.ndarray, kinds: tuple[str, ...], h: float, qdd=None
    ) -> SafeCommand:
        """Make ``(q, v)`` the commanded state of this tick and count the interventions
        (``qdd``: ``(v - qd) / h`` computed ahead)."""
        for kind in kinds:
            self.counts[kind] += 1
        self.ticks += 1
        if kinds or self.braking:
            self.intervened += 1
        self._qdd_prev, self.qdd = self.qdd, (v - self.qd) / h if qdd is None else qdd
        if qdd is None:  # (filtered ahead: frozen already)
            q.setflags(write=False)  # fresh arrays each tick: safe to hand out read-only
            v.setflags(write=False)
        self.q, self.qd = q, v
        self.state += 1
        self._head = (self._head + 1) % self._window
        self._recent[self._head] = q
        self._recent_v[self._head] = v
        return SafeCommand(q, v, self.braking, self.braking and not v.any(), kinds)
