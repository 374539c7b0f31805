"""Safety supervisor: the last stage before the wire, independent of the planner.

Every 4 ms tick it takes the planner's requested ``(q, qd)`` and the previous *commanded* state
and returns a command that is guaranteed, whatever the request (NaN, inf, 1e300, jumps):

* inside the position limits shrunk by a margin: ``q_min <= q <= q_max``;
* ``|qd| <= v_max`` and ``|qd - qd_prev| <= a_max * dt``;
* finite;
* *recoverable*: from every commanded state, braking at ``a_max`` stops inside the limits.

The last property is the invariant that makes the others provable. With trapezoidal integration
``q' = q + (v + v') dt / 2`` and braking ``v' = v - sign(v) min(|v|, a dt)``, a state with
``q + v^2 / (2a) + |v| dt / 2 <= q_max`` (for ``v > 0``; mirrored for the lower limit) keeps
satisfying it after a braking tick, so the braking velocity is always admissible and the set of
admissible next velocities is never empty. Requests that are admissible and consistent with the
previous state (their position step matches some ``|acc| <= a_max`` motion) pass unchanged;
anything else is replaced by the admissible velocity closest to one that tracks the request.

Braking (on a stop signal, feedback deviation or a non-finite request)
drives every joint's velocity to zero along the time-optimal jerk-limited stop from the commanded
velocity and acceleration (:class:`JerkLimitedStop`, Ruckig's velocity interface), or, where
Ruckig refuses the state, with ``|acc| <= a_max`` and the acceleration ramped at ``j_max`` (a
sqrt law). Jerk is honoured unless the state
when braking starts makes it impossible without reversing (then the velocity stops at zero), or
a position limit demands a harder stop. Joints brake independently (each as fast as it may).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory

from thinkfast.config import spec
from thinkfast.errors import ThinkfastError

CLAMP_KINDS = ("nonfinite", "velocity", "acceleration", "position_step", "position_limit")
BRAKE_REASONS = ("signal", "deviation", "nonfinite")
REL_TOL = 1e-9  # a request exactly at a limit passes (a planner at the limit, rounded up)
KINDS = CLAMP_KINDS + tuple(f"brake_{r}" for r in BRAKE_REASONS) + ("init_clamped", "resync")


class SafetyError(ThinkfastError):
    """Limits handed to the supervisor are unusable (shape, sign, margin larger than the range)."""


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
    max_faults: int = spec(
        3, doc="this many faults within fault_window latch fault until restarted", lo=1
    )
    fault_window: float = spec(
        60.0, doc="window for counting faults towards max_faults", unit="s", lo=0.0, lo_open=True
    )


class SafetyLimits(NamedTuple):
    """Per-joint limits the supervisor enforces, each shape (n,), read-only.

    Attributes:
        q_min, q_max: position limits already shrunk by the margin [rad].
        v_max: velocity limits [rad/s], > 0.
        a_max: acceleration limits [rad/s^2], > 0.
        j_max: jerk limits for braking [rad/s^3], > 0.
    """

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    j_max: np.ndarray


def make_limits(q_lower, q_upper, v_max, a_max, j_max, margin: float = 0.0) -> SafetyLimits:
    """Validate and freeze limits; positions are shrunk by ``margin`` [rad] on both sides.

    Raises:
        SafetyError: shapes differ, a value is not finite, a v/a/j limit is not > 0, or the
            margin leaves no room (``q_upper - q_lower <= 2 margin``).
    """
    arrs = [np.array(x, dtype=float).reshape(-1) for x in (q_lower, q_upper, v_max, a_max, j_max)]
    names = ("q_lower", "q_upper", "v_max", "a_max", "j_max")
    n = arrs[0].size
    for name, a in zip(names, arrs, strict=True):
        if a.size != n or not np.isfinite(a).all():
            raise SafetyError(f"safety limits: {name} must hold {n} finite values, got {a}")
    for name, a in zip(names[2:], arrs[2:], strict=True):
        if (a <= 0).any():
            raise SafetyError(f"safety limits: {name} must be > 0, got {a}")
    lo, hi = arrs[0] + margin, arrs[1] - margin
    if (hi <= lo).any():
        raise SafetyError(
            f"safety limits: margin {margin} rad leaves no range in {arrs[0]}..{arrs[1]}"
        )
    out = [lo, hi, *arrs[2:]]
    for a in out:
        a.setflags(write=False)
    return SafetyLimits(*out)


def robot_limits(robot, margin: float) -> SafetyLimits:
    """:func:`make_limits` from a loaded robot's URDF and robot.toml limits."""
    return make_limits(robot.q_lower, robot.q_upper, robot.v_max, robot.a_max, robot.j_max, margin)


def _room_speed(r: np.ndarray, a: np.ndarray, dt: float) -> np.ndarray:
    """Largest next speed towards a limit at distance ``r`` (after half a tick at the old speed)
    that can still be braked at ``a`` without passing it."""
    root = a * (np.sqrt(dt * dt + 2.0 * np.maximum(r, 0.0) / a) - dt)
    return np.where(r >= 0.0, root, 2.0 * r / dt)


def velocity_bounds(q_p, v_p, lim: SafetyLimits, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Admissible next velocities ``[lo, hi]`` from the commanded state ``(q_p, v_p)``.

    Intersection of ``|v| <= v_max``, ``|v - v_p| <= a_max dt`` and the braking-room invariant.
    Contains the braking velocity whenever ``(q_p, v_p)`` satisfies the invariant.
    """
    half = q_p + 0.5 * v_p * dt
    hi = np.minimum(
        np.minimum(lim.v_max, v_p + lim.a_max * dt), _room_speed(lim.q_max - half, lim.a_max, dt)
    )
    lo = np.maximum(
        np.maximum(-lim.v_max, v_p - lim.a_max * dt), -_room_speed(half - lim.q_min, lim.a_max, dt)
    )
    return lo, hi


def recoverable(q, v, lim: SafetyLimits, dt: float) -> np.ndarray:
    """Per joint: inside the limits and able to brake at ``a_max`` without leaving them."""
    return _recoverable(q, v, lim, _TickConstants.of(lim, dt))


def _recoverable(q, v, lim: SafetyLimits, k: _TickConstants) -> np.ndarray:
    end = q + v * (np.abs(v) / k.two_a + k.half_dt)  # where braking now would stop
    return (np.minimum(q, end) >= lim.q_min) & (np.maximum(q, end) <= lim.q_max)


def limit_step(q_p, v_p, v_des, lim: SafetyLimits, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The admissible next state whose velocity is closest to ``v_des`` (finite, shape (n,)).

    Returns:
        ``(q, v)``: ``v`` clipped into :func:`velocity_bounds` (the braking velocity if rounding
        empties them), ``q`` its trapezoidal integral.
    """
    lo, hi = velocity_bounds(q_p, v_p, lim, dt)
    v_brake = v_p - np.sign(v_p) * np.minimum(np.abs(v_p), lim.a_max * dt)
    v = np.where(lo <= hi, np.clip(v_des, lo, hi), v_brake)
    v = np.clip(v, -lim.v_max, lim.v_max)
    q = np.clip(q_p + 0.5 * (v_p + v) * dt, lim.q_min, lim.q_max)
    return q, v


def brake_velocity(v_p, a_p, lim: SafetyLimits, dt: float) -> np.ndarray:
    """Next velocity of a jerk-limited stop from velocity ``v_p`` and acceleration ``a_p``.

    Per joint, in the direction of motion ``u = |v|``: the deceleration ``b`` grows at jerk
    ``j_max`` up to ``a_max`` as long as ramping it back to zero still ends at rest (about
    ``b = sqrt(2 j u)``), then shrinks at ``j_max``; the velocity never changes sign.
    """
    s = np.sign(v_p)
    j = lim.j_max
    u, b = np.abs(v_p), np.clip(s * a_p, -lim.a_max, lim.a_max)
    # Acceleration is constant over a tick (v' = v + b' dt). Strongest deceleration x = -b'
    # such that ramping it back to zero in steps of j dt still removes no more than the speed
    # left: u - x dt >= x^2 / (2 j) - x dt / 2 (root written without cancellation, so that
    # tiny speeds still end at exactly zero).
    x = 2.0 * u / (np.sqrt(0.25 * dt * dt + 2.0 * u / j) + 0.5 * dt)
    b_new = np.clip(np.clip(-x, b - j * dt, b + j * dt), -lim.a_max, lim.a_max)
    u_new = np.maximum(u + b_new * dt, 0.0)
    return s * u_new


class JerkLimitedStop:
    """The time-optimal stop of every joint from velocity and acceleration (Ruckig's velocity
    interface, joints independent), sampled tick by tick: the commanded velocity follows a
    continuous jerk-limited profile, so braking honours j_max exactly (where the position
    limits allow; :func:`limit_step` still guards them)."""

    def __init__(self, traj: Trajectory, v0: np.ndarray):
        self._traj, self._t = traj, 0.0
        self._sign = np.sign(v0)  # a stop never reverses: a joint that reaches zero stays

    @classmethod
    def plan(cls, v0, a0, lim: SafetyLimits) -> JerkLimitedStop | None:
        """The stop from ``v0`` [rad/s], ``a0`` [rad/s^2] (n,), or None when Ruckig refuses
        (the supervisor then brakes with :func:`brake_velocity`)."""
        n = lim.v_max.size
        v0, a0 = np.asarray(v0, dtype=float), np.asarray(a0, dtype=float)
        if not (np.isfinite(v0).all() and np.isfinite(a0).all()):
            return None
        inp = InputParameter(n)
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.current_position = [0.0] * n
        inp.current_velocity = v0.tolist()
        a0 = np.clip(a0, -lim.a_max, lim.a_max)
        # an acceleration that would carry the speed past v_max before it ramps down is the
        # estimate's error, not the plan's: take the largest that just reaches v_max
        room = np.maximum(lim.v_max - np.abs(v0), 0.0)
        a_top = np.sqrt(2.0 * lim.j_max * room)
        away = a0 * np.sign(v0) > a_top
        a0 = np.where(away, np.sign(v0) * a_top, a0)
        inp.current_acceleration = a0.tolist()
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
        inp.max_velocity = np.maximum(lim.v_max, np.abs(v0) * (1 + 1e-9)).tolist()
        inp.max_acceleration = lim.a_max.tolist()
        inp.max_jerk = lim.j_max.tolist()
        traj = Trajectory(n)
        try:
            result = Ruckig(n).calculate(inp, traj)
        except Exception:  # ruckig.RuckigError: a state it cannot plan from
            return None
        if result not in (Result.Working, Result.Finished) or not math.isfinite(traj.duration):
            return None
        return cls(traj, v0)

    def next(self, h: float) -> np.ndarray:
        """The stop's velocity [rad/s] (n,) ``h`` seconds after the previous call."""
        self._t = min(self._t + h, self._traj.duration)
        v = np.array(self._traj.at_time(self._t)[1])
        v = np.where((v * self._sign > 0.0) & (np.abs(v) >= 1e-9), v, 0.0)
        self._sign = np.where(v == 0.0, 0.0, self._sign)
        return v


class StepResult(NamedTuple):
    """One filtered command: ``q`` [rad], ``qd`` [rad/s], shape (n,), and the kinds applied."""

    q: np.ndarray
    qd: np.ndarray
    kinds: tuple[str, ...]


def filter_step(q_p, v_p, q_req, v_req, lim: SafetyLimits, dt: float) -> StepResult:
    """Make the requested next state admissible (pure; the non-braking path of the supervisor).

    Args:
        q_p, v_p: previous commanded state [rad], [rad/s], shape (n,), recoverable.
        q_req, v_req: requested state, shape (n,), finite.
        lim: limits. dt: tick [s].

    Returns:
        The request itself when admissible, else the closest admissible state; ``kinds`` lists
        which checks the request failed (empty when it passed).
    """
    with np.errstate(over="ignore", invalid="ignore"):  # 1e300-sized requests: inf compares fine
        return _filter_step(q_p, v_p, q_req, v_req, lim, dt, _TickConstants.of(lim, dt))


class _TickConstants(NamedTuple):
    """Products of the limits and the tick that every step uses (computed once, same floats)."""

    a_dt: np.ndarray  # a_max dt (1 + REL_TOL): largest velocity change of a request per tick
    v_tol: np.ndarray  # v_max (1 + REL_TOL): largest speed of a request
    step_tol: np.ndarray  # largest position error of an admissible request
    two_a: np.ndarray
    half_dt: float

    @classmethod
    def of(cls, lim: SafetyLimits, dt: float) -> _TickConstants:
        a_dt = lim.a_max * dt
        return cls(
            a_dt * (1.0 + REL_TOL),
            lim.v_max * (1.0 + REL_TOL),
            0.25 * a_dt * dt * (1.0 + REL_TOL),
            2.0 * lim.a_max,
            0.5 * dt,
        )


def _any(mask: np.ndarray) -> bool:
    """``mask.any()`` without its Python-level overhead (a sixth of the time on 6 joints)."""
    return _count_nonzero(mask) > 0


_count_nonzero = np.count_nonzero


def _filter_step(
    q_p, v_p, q_req, v_req, lim: SafetyLimits, dt: float, k: _TickConstants
) -> StepResult:
    kinds = []
    if _any(np.abs(v_req) > k.v_tol):
        kinds.append("velocity")
    if _any(np.abs(v_req - v_p) > k.a_dt):
        kinds.append("acceleration")
    err = q_req - (q_p + 0.5 * (v_p + v_req) * dt)
    if _any(np.abs(err) > k.step_tol):
        kinds.append("position_step")
    if _any(~_recoverable(q_req, v_req, lim, k)):
        kinds.append("position_limit")
    if not kinds:
        return StepResult(np.array(q_req, dtype=float), np.array(v_req, dtype=float), ())
    # Track the request: its velocity plus a correction that closes the position error at a
    # rate a_max/2 could stop (sqrt law), linear near zero so it settles without chatter.
    err = np.clip(err, -1e3, 1e3)
    fix = np.sign(err) * np.minimum(np.abs(err) / (4.0 * dt), np.sqrt(lim.a_max * np.abs(err)))
    q, v = limit_step(q_p, v_p, np.clip(v_req, -lim.v_max, lim.v_max) + fix, lim, dt)
    return StepResult(q, v, tuple(kinds))


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
    """

    q_req: object
    qd_req: object
    state: int
    result: tuple | None


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
        self._k = _TickConstants.of(limits, config.dt)
        self._window = max(1, math.ceil(config.tracking_lag / config.dt - 1e-9)) + 1
        self.reset(q0)

    def reset(self, q0, qd0=None) -> None:
        """Start at ``q0`` [rad] moving at ``qd0`` [rad/s] (default: rest), no brake latched.

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
        self.q, self.qd, self.qdd = q, v, np.zeros(n)
        self._qdd_prev = self.qdd
        self.brake_reason: str | None = None
        self._stop: JerkLimitedStop | None = None
        self.state += 1
        self._recent = np.tile(q, (self._window, 1))  # ring of recent commands (envelope)
        self._recent_v = np.tile(v, (self._window, 1))
        self._head = 0

    def resync(self, q_meas, qd_meas=None) -> bool:
        """Restart from the measured state (after an EGM silence): returns False when the
        measurement is unusable (the state is kept and a ``deviation`` brake latched)."""
        try:
            self.reset(q_meas, qd_meas)
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
        return not self.qd.any()

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
        q = _vector(q_meas, self.q.size)
        if q is None:
            return None
        recent = self._recent
        outside = np.maximum(np.maximum(q - recent.max(axis=0), recent.min(axis=0) - q), 0.0)
        overshoot = self.config.servo_time_constant * np.abs(self._recent_v).max(axis=0)
        return np.maximum(outside - overshoot, 0.0)

    def filter_ahead(self, q_req, qd_req) -> Ahead:
        """Filter the next tick's request ahead of time, to take work out of the tick.

        Pure: no state changes. :meth:`step_ahead` uses the result when the commanded state is
        still the one it was filtered from, the tick is nominal and no brake is latched by then:
        exactly what :meth:`step` would compute (the same :func:`filter_step` from the same
        previous command); otherwise it steps afresh.
        """
        n = self.q.size
        q_r, v_r = _vector(q_req, n), _vector(qd_req, n)
        if q_r is None or v_r is None:
            return Ahead(q_req, qd_req, self.state, None)
        with np.errstate(over="ignore", invalid="ignore"):  # as in filter_step
            res = _filter_step(self.q, self.qd, q_r, v_r, self.limits, self.config.dt, self._k)
        return Ahead(q_req, qd_req, self.state, res)

    def step_ahead(self, ahead: Ahead, q_meas=None, dt: float | None = None) -> SafeCommand:
        """:meth:`step` on the request of ``ahead``, using its filter result when it still
        applies (see :meth:`filter_ahead`). Never raises."""
        usable = ahead.result is not None and ahead.state == self.state
        if not usable or (dt is not None and dt != self.config.dt):
            return self.step(ahead.q_req, ahead.qd_req, q_meas, dt)
        self._check_feedback(q_meas)
        if self.braking:
            return self.step(ahead.q_req, ahead.qd_req)
        q, v, kinds = ahead.result
        return self._commit(q, v, kinds, self.config.dt)

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
        k = self._k if nominal else _TickConstants.of(lim, dt)
        h = cfg.dt if nominal else dt
        q_r, v_r = _vector(q_req, n), _vector(qd_req, n)
        if not self.braking and (q_r is None or v_r is None):
            kinds = ("nonfinite",)
            self.request_brake("nonfinite")
        if self.braking:
            if self._stop is not None:  # a joint that stood (a limit stopped it) stays
                v_des = np.where(self.qd == 0.0, 0.0, self._stop.next(h))
            else:
                v_des = brake_velocity(self.qd, self.qdd, lim, h)
            q, v = limit_step(self.q, self.qd, v_des, lim, h)
            # rounding in the limit bounds can leave +-1e-13 rad/s of the wrong sign: a stop
            # is exactly zero, never a reversal
            v = np.where(np.abs(v) < 1e-9, 0.0, v)
        else:
            with np.errstate(over="ignore", invalid="ignore"):  # as in filter_step
                q, v, kinds = _filter_step(self.q, self.qd, q_r, v_r, lim, h, k)
        return self._commit(q, v, kinds, h)

    def _check_feedback(self, q_meas) -> None:
        """Brake on feedback outside the envelope of recent commands (None: no feedback)."""
        if q_meas is not None:
            dev = self.deviation(q_meas)
            if dev is None or _any(dev > self.config.max_deviation):
                self.request_brake("deviation")

    def _commit(
        self, q: np.ndarray, v: np.ndarray, kinds: tuple[str, ...], h: float
    ) -> SafeCommand:
        """Make ``(q, v)`` the commanded state of this tick and count the interventions."""
        for kind in kinds:
            self.counts[kind] += 1
        self.ticks += 1
        if kinds or self.braking:
            self.intervened += 1
        self._qdd_prev, self.qdd = self.qdd, (v - self.qd) / h
        q.setflags(write=False)  # fresh arrays each tick: safe to hand out read-only
        v.setflags(write=False)
        self.q, self.qd = q, v
        self.state += 1
        self._head = (self._head + 1) % self._window
        self._recent[self._head] = q
        self._recent_v[self._head] = v
        return SafeCommand(q, v, self.braking, self.braking and not v.any(), kinds)


def _vector(x, n: int) -> np.ndarray | None:
    """``x`` as a finite float array of shape (n,), or None (bad shape, type or value)."""
    try:
        a = np.array(x, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        return None
    if a.size != n or _count_nonzero(np.isfinite(a)) != n:
        return None
    return a
