"""Braking: the jerk-limited stop the safety supervisor commands once a brake is latched.

Every joint's velocity is driven to zero along the time-optimal jerk-limited stop from the
commanded velocity and acceleration (:class:`JerkLimitedStop`, Ruckig's velocity interface), or,
where Ruckig refuses the state, with ``|acc| <= a_max`` and the acceleration ramped at ``j_max``
(a sqrt law, :func:`brake_velocity`). A stop does not reverse a joint, but for one that is
turning round already when the brake starts: its acceleration opposes its velocity and is too
large to ramp to zero at ``j_max`` before the velocity passes zero (``a^2 / (2 j_max) > |v|``).
That joint follows Ruckig's stop through zero and back to rest, where cutting its velocity at
zero would step the acceleration down in one tick (seen at 5 to 9 times ``j_max`` on joint 3 in
the fault campaign: from -0.25 rad/s and +11.8 rad/s^2 it now goes back 16 mrad, at 0.21 rad/s
at most). Jerk is honoured unless a position limit demands a harder stop
(:func:`thinkfast.control.safety_limits.limit_step` still guards them), or Ruckig refuses the
state (the sqrt law then stops at zero). Joints brake independently (each as fast as it may).
Pure: no clock, no I/O.
"""

from __future__ import annotations

import math

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory

from thinkfast.control.safety_limits import SafetyLimits
from thinkfast.robot.steering import feasible_acceleration


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


def stop_trajectory(p0, v0, a0, limits, sync: bool) -> Trajectory | None:
    """Ruckig's time-optimal stop (its velocity interface) from positions ``p0`` [rad],
    velocities ``v0`` [rad/s] and accelerations ``a0`` [rad/s^2] (n,) within ``limits`` =
    (v_max, a_max, j_max) (n,) each; ``sync``: every joint at rest at the same time, else each
    as soon as it can. None when Ruckig refuses the state."""
    n = len(v0)
    inp = InputParameter(n)
    inp.control_interface = ControlInterface.Velocity
    if not sync:
        inp.synchronization = Synchronization.No
    inp.current_position = [float(x) for x in p0]
    inp.current_velocity = [float(x) for x in v0]
    inp.current_acceleration = [float(x) for x in a0]
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = ([float(x) for x in m] for m in limits)
    traj = Trajectory(n)
    try:
        result = Ruckig(n).calculate(inp, traj)
    except Exception:  # ruckig.RuckigError: a state it cannot plan from
        return None
    if result not in (Result.Working, Result.Finished) or not math.isfinite(traj.duration):
        return None
    return traj


class JerkLimitedStop:
    """The time-optimal stop of every joint from velocity and acceleration (Ruckig's velocity
    interface, joints independent), sampled tick by tick: the commanded velocity follows a
    continuous jerk-limited profile, so braking honours j_max exactly (where the position
    limits allow; :func:`limit_step` still guards them). A joint that reaches zero stays there,
    unless it was turning round as the stop began (:func:`turning`): that one follows the
    profile through zero and back to rest."""

    def __init__(self, traj: Trajectory, v0: np.ndarray, through: np.ndarray):
        self._traj, self._t = traj, 0.0
        self._sign = np.sign(v0)  # the direction a joint may not leave (0: it stands)
        self.through = through  # (n,) bool: turning round as the stop began

    @classmethod
    def plan(cls, v0, a0, lim: SafetyLimits) -> JerkLimitedStop | None:
        """The stop from ``v0`` [rad/s], ``a0`` [rad/s^2] (n,), or None when Ruckig refuses
        (the supervisor then brakes with :func:`brake_velocity`)."""
        n = lim.v_max.size
        v0, a0 = np.asarray(v0, dtype=float), np.asarray(a0, dtype=float)
        if not (np.isfinite(v0).all() and np.isfinite(a0).all()):
            return None
        # an acceleration that would carry the speed past v_max before it ramps down is the
        # estimate's error, not the plan's: take the largest that just reaches v_max
        a0 = feasible_acceleration(v0, a0, lim.v_max, lim.a_max, lim.j_max)
        v_lim = np.maximum(lim.v_max, np.abs(v0) * (1 + 1e-9))
        traj = stop_trajectory(np.zeros(n), v0, a0, (v_lim, lim.a_max, lim.j_max), sync=False)
        if traj is None:
            return None
        return cls(traj, v0, turning(v0, a0, lim.j_max))

    def next(self, h: float) -> np.ndarray:
        """The stop's velocity [rad/s] (n,) ``h`` seconds after the previous call."""
        self._t = min(self._t + h, self._traj.duration)
        if self._t >= self._traj.duration:  # at rest, exactly (whatever Ruckig's rounding)
            return np.zeros(self._sign.size)
        v = np.array(self._traj.at_time(self._t)[1])
        keep = (self.through | (v * self._sign > 0.0)) & (np.abs(v) >= 1e-9)
        v = np.where(keep, v, 0.0)
        self._sign = np.where(v == 0.0, 0.0, self._sign)
        return v


def turning(v, a, j_max) -> np.ndarray:
    """Per joint, whether no stop at ``j_max`` keeps the velocity ``v`` [rad/s] (n,) from
    passing zero: the acceleration ``a`` [rad/s^2] (n,) opposes it (or the joint stands) and
    ramping it to zero changes the velocity by more than is left (``a^2 / (2 j_max) > |v|``)."""
    v, a = np.asarray(v, dtype=float), np.asarray(a, dtype=float)
    return (a * v <= 0.0) & (a * a > 2.0 * j_max * np.abs(v))
