"""Admissible commands: the pure limit kernels of the safety supervisor.

From the previous *commanded* state and a requested ``(q, qd)`` these functions return a next
state that is, whatever the request (NaN, inf, 1e300, jumps):

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

No state, clock or I/O: :class:`thinkfast.control.safety.SafetySupervisor` composes them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.errors import ThinkfastError

CLAMP_KINDS = ("nonfinite", "velocity", "acceleration", "position_step", "position_limit")
REL_TOL = 1e-9  # a request exactly at a limit passes (a planner at the limit, rounded up)


class SafetyError(ThinkfastError):
    """Limits handed to the supervisor are unusable (shape, sign, margin larger than the range)."""


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
    return recoverable_k(q, v, lim, TickConstants.of(lim, dt))


def recoverable_k(q, v, lim: SafetyLimits, k: TickConstants) -> np.ndarray:
    """:func:`recoverable` with the tick's constants computed once (:class:`TickConstants`)."""
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
        return filter_tick(q_p, v_p, q_req, v_req, lim, dt, TickConstants.of(lim, dt))


class TickConstants(NamedTuple):
    """Products of the limits and the tick that every step uses (computed once, same floats)."""

    a_dt: np.ndarray  # a_max dt (1 + REL_TOL): largest velocity change of a request per tick
    v_tol: np.ndarray  # v_max (1 + REL_TOL): largest speed of a request
    step_tol: np.ndarray  # largest position error of an admissible request
    two_a: np.ndarray
    half_dt: float

    @classmethod
    def of(cls, lim: SafetyLimits, dt: float) -> TickConstants:
        """The constants of ``lim`` for a tick of ``dt`` [s]."""
        a_dt = lim.a_max * dt
        return cls(
            a_dt * (1.0 + REL_TOL),
            lim.v_max * (1.0 + REL_TOL),
            0.25 * a_dt * dt * (1.0 + REL_TOL),
            2.0 * lim.a_max,
            0.5 * dt,
        )


def any_true(mask: np.ndarray) -> bool:
    """``mask.any()`` without its Python-level overhead (docs/BENCHMARKS.md, "Kernel figures the
    code refers to")."""
    return _count_nonzero(mask) > 0


_count_nonzero = np.count_nonzero


def filter_tick(
    q_p, v_p, q_req, v_req, lim: SafetyLimits, dt: float, k: TickConstants
) -> StepResult:
    """:func:`filter_step` with the tick's constants ``k`` computed once (the supervisor's
    per-tick path); the caller silences numpy's overflow warnings (1e300-sized requests)."""
    kinds = []
    if any_true(np.abs(v_req) > k.v_tol):
        kinds.append("velocity")
    if any_true(np.abs(v_req - v_p) > k.a_dt):
        kinds.append("acceleration")
    err = q_req - (q_p + 0.5 * (v_p + v_req) * dt)
    if any_true(np.abs(err) > k.step_tol):
        kinds.append("position_step")
    if any_true(~recoverable_k(q_req, v_req, lim, k)):
        kinds.append("position_limit")
    if not kinds:
        return StepResult(np.array(q_req, dtype=float), np.array(v_req, dtype=float), ())
    # Track the request: its velocity plus a correction that closes the position error at a
    # rate a_max/2 could stop (sqrt law), linear near zero so it settles without chatter.
    err = np.clip(err, -1e3, 1e3)
    fix = np.sign(err) * np.minimum(np.abs(err) / (4.0 * dt), np.sqrt(lim.a_max * np.abs(err)))
    q, v = limit_step(q_p, v_p, np.clip(v_req, -lim.v_max, lim.v_max) + fix, lim, dt)
    return StepResult(q, v, tuple(kinds))


def beyond_envelope(q, bounds: tuple, max_deviation: float) -> bool:
    """A joint of ``q`` [rad] (n values) lies further than ``max_deviation`` outside the
    envelope ``bounds`` = ``(hi, lo, overshoot)`` (n floats each: the highest and lowest command
    of the window, the overshoot a following servo may add), or ``q`` is not n finite values:
    the decision of :meth:`SafetySupervisor.deviation` compared with ``max_deviation``, the same
    floating-point operations in plain floats (six joints: cheaper than numpy's calls)."""
    hi, lo, overshoot = bounds
    if isinstance(q, np.ndarray) and q.ndim == 1 and q.dtype == np.float64:
        vals = q.tolist()
    else:
        a = finite_vector(q, len(hi))
        if a is None:
            return True
        vals = a.tolist()
    if len(vals) != len(hi):
        return True
    for x, h, lo_j, o in zip(vals, hi, lo, overshoot, strict=True):
        if not math.isfinite(x):
            return True
        above, below = x - h, lo_j - x
        outside = above if above > below else below
        dev = (outside if outside > 0.0 else 0.0) - o
        if (dev if dev > 0.0 else 0.0) > max_deviation:
            return True
    return False


def finite_vector(x, n: int) -> np.ndarray | None:
    """``x`` as a finite float array of shape (n,), or None (bad shape, type or value)."""
    try:
        a = np.array(x, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        return None
    if a.size != n or _count_nonzero(np.isfinite(a)) != n:
        return None
    return a
