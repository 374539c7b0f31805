"""Simulated throws: sampling, the drag ODE, release velocity by shooting.

A throw starts with the ball in the thrower's hand ``t_release`` seconds before the release: held
still (small hand motion), and for a ``windup`` then swung back and forward to the release
(``thinkfast/sim/thrower.py``; a ``feint`` stops its forward swing and is never released); it
then flies from ``p_release`` with ``v_release`` under gravity and quadratic air drag
``a = (0, 0, -g) - k |v| v``, all in ``base`` (REP-103, z up). Time ``t`` is measured from release
(negative in the hand). The release velocity is solved so that the ball centre reaches the aim
point ``(plane_x, y, z)`` exactly at the chosen flight time, with drag.

Integration is classical RK4 on a fixed grid of :data:`STEP` seconds from release; a state between
grid nodes takes one partial RK4 step from the node before it, so every query is as accurate as
the grid (about 1e-11 m at 5 ms against a tight adaptive solver, checked in the tests).
Throw-set files: ``thinkfast/sim/throwset.py``, ``docs/THROW_SET_FORMAT.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.errors import ConfigError, NoSolutionError
from thinkfast.sim.thrower import DRAWS, ThrowerConfig, sample_motion, swing_states

STEP = 0.005
"""RK4 grid step [s]."""
FEINT_KEY = 0x46454E54
"""First spawn-key element of the seed sequences of feints appended to a sampled set."""


def _rng(doc: str, default: tuple[float, float], unit: str = "m", lo: float | None = None) -> Any:
    return spec(default, doc=f"{doc} (uniform between the two values)", unit=unit, lo=lo, length=2)


@dataclasses.dataclass(frozen=True)
class ThrowConfig:
    """How throws are drawn. Ranges are (low, high) of a uniform draw; ASSUMPTIONS noted inline.

    Defaults follow docs/FACTS.md (the paper's experiment: 6-8 m, 0.4-0.8 s to the plane) and a
    tennis ball (57 g, 67 mm, Cd 0.55) in air of 1.2 kg/m^3.
    """

    plane_distance: float = spec(0.8, doc="intercept plane x in base", unit="m", lo=0.0)
    release_distance: tuple[float, float] = _rng("release x beyond the plane", (6.0, 8.0), lo=0.0)
    release_height: tuple[float, float] = _rng("release z (ASSUMPTION: adult thrower)", (1.0, 1.8))
    release_lateral: tuple[float, float] = _rng("release y (ASSUMPTION)", (-1.0, 1.0))
    flight_time: tuple[float, float] = _rng("release to plane", (0.4, 0.8), unit="s", lo=0.05)
    aim_y: tuple[float, float] = _rng("aim y on the plane (region to protect)", (-0.9, 0.9))
    aim_z: tuple[float, float] = _rng("aim z on the plane (region to protect)", (0.25, 1.75))
    hold_time: tuple[float, float] = _rng("ball still in hand before release", (0.3, 0.8), "s", 0.0)
    hand_motion: float = spec(
        0.003, doc="hand motion amplitude per axis while holding (ASSUMPTION)", unit="m", lo=0.0
    )
    hand_frequency: tuple[float, float] = _rng("hand motion frequency", (0.5, 2.0), "Hz", 0.0)
    ball_mass: float = spec(0.057, doc="ball mass (tennis ball)", unit="kg", lo=0.0, lo_open=True)
    ball_radius: float = spec(0.0335, doc="ball radius (67 mm ball)", unit="m", lo=0.0)
    drag_coefficient: float = spec(0.55, doc="drag coefficient Cd (tennis ball)", lo=0.0)
    air_density: float = spec(1.2, doc="air density", unit="kg/m^3", lo=0.0)
    gravity: float = spec(9.81, doc="gravity along -z of base", unit="m/s^2", lo=0.0)
    thrower: ThrowerConfig = spec(
        ThrowerConfig(), doc="kinds of throw (mix) and wind-up / feint motions, ASSUMED"
    )

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, tuple) and len(v) == 2 and v[0] > v[1]:
                raise ConfigError("throw config", f.name, f"low {v[0]:g} > high {v[1]:g}")

    def drag_k(self) -> float:
        """Quadratic drag coefficient ``k = rho Cd A / (2 m)`` [1/m] (about 0.0204 by default)."""
        area = math.pi * self.ball_radius**2
        return self.air_density * self.drag_coefficient * area / (2.0 * self.ball_mass)


def aimed_at(cfg: ThrowConfig, plane_x: float, aim_y=None, aim_z=None) -> ThrowConfig:
    """``cfg`` aimed at the plane ``x = plane_x`` [m] and the region ``aim_y`` x ``aim_z``
    ((low, high) [m]; None: unchanged). Values equal to ``cfg``'s leave it as it is (the same
    throws, bit for bit)."""
    out = {}
    if float(plane_x) != cfg.plane_distance:
        out["plane_distance"] = float(plane_x)
    for key, value in (("aim_y", aim_y), ("aim_z", aim_z)):
        if value is not None and tuple(map(float, value)) != tuple(getattr(cfg, key)):
            out[key] = tuple(map(float, value))
    return dataclasses.replace(cfg, **out) if out else cfg


_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


class Throw(NamedTuple):
    """One throw, everything needed to replay it (arrays read-only).

    Attributes:
        id: ``"s<seed>-<index>"``, stable for a seed whatever the number of throws drawn.
        t_release: hold before release [s]: the ball appears in the hand at ``t = -t_release``.
        p_release: release position in base [m], shape (3,).
        v_release: release velocity in base [m/s], shape (3,).
        drag: quadratic drag coefficient k [1/m].
        aim: aim point (y, z) on the plane [m], shape (2,).
        flight_time: release to plane crossing [s].
        gravity: gravity along -z [m/s^2].
        plane_x: the plane the throw is aimed at [m].
        hand_amp, hand_freq, hand_phase: hand motion per axis [m], [Hz], [rad], shape (3,) each.
        kind: ``"still"``, ``"windup"`` or ``"feint"`` (``thinkfast/sim/thrower.py``).
        back_time: back swing duration [s] (0 for ``still``).
        back_swing: back swing displacement (hold point to forward swing start) [m], (3,).
        back_sag: back swing path offset from its chord at mid swing [m], (3,).
        forward_time: forward swing duration [s], ending at ``t = 0``.
        forward_swing: forward swing displacement (its start to ``p_release``) [m], (3,).
        rest_time: a feint's ball stays still at ``p_release`` this long after ``t = 0`` [s].

    A feint is never released: ``p_release`` is where its ball stops, ``v_release`` is zero,
    ``aim`` and ``flight_time`` are those of the throw it feigned (never flown).
    """

    id: str
    t_release: float
    p_release: np.ndarray
    v_release: np.ndarray
    drag: float
    aim: np.ndarray
    flight_time: float
    gravity: float
    plane_x: float
    hand_amp: np.ndarray
    hand_freq: np.ndarray
    hand_phase: np.ndarray
    kind: str = "still"
    back_time: float = 0.0
    back_swing: np.ndarray = _ZERO3
    back_sag: np.ndarray = _ZERO3
    forward_time: float = 0.0
    forward_swing: np.ndarray = _ZERO3
    rest_time: float = 0.0


class TrueCrossing(NamedTuple):
    """Ball centre at the plane: time after release [s], y, z [m], velocity [m/s] (3,)."""

    t: float
    y: float
    z: float
    v: np.ndarray


def _frozen(a: Any) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def _deriv(y: np.ndarray, k: float, g: float) -> np.ndarray:
    v = y[..., 3:]
    a = -k * np.linalg.norm(v, axis=-1, keepdims=True) * v
    a[..., 2] -= g
    return np.concatenate([v, a], axis=-1)


def _rk4(y: np.ndarray, h: np.ndarray | float, k: float, g: float) -> np.ndarray:
    """One RK4 step of size ``h`` [s] (scalar, or (B, 1) per row) for states ``y`` (B, 6)."""
    k1 = _deriv(y, k, g)
    k2 = _deriv(y + 0.5 * h * k1, k, g)
    k3 = _deriv(y + 0.5 * h * k2, k, g)
    k4 = _deriv(y + h * k3, k, g)
    return y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _drag_gravity(v: tuple, k: float, g: float) -> tuple:
    """:func:`_deriv`'s acceleration [m/s^2] for one velocity ``v`` (3 floats), in Python floats:
    the norm's squares summed x, y then z, as numpy's reduction does."""
    c = -k * math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return (c * v[0], c * v[1], c * v[2] - g)


def _rk4_row(y: tuple, h: float, k: float, g: float) -> tuple:
    """:func:`_rk4` for one state ``y`` (6 floats) and a scalar ``h`` [s], in Python floats.

    The same operations in the same order as the array version, so the same values bit for
    bit (tests/test_sim_throws.py); without numpy's cost per call on six numbers.
    """
    v1, hh = y[3:], 0.5 * h  # the velocities at the four stages: the position's derivatives
    a1 = _drag_gravity(v1, k, g)
    v2 = (v1[0] + hh * a1[0], v1[1] + hh * a1[1], v1[2] + hh * a1[2])
    a2 = _drag_gravity(v2, k, g)
    v3 = (v1[0] + hh * a2[0], v1[1] + hh * a2[1], v1[2] + hh * a2[2])
    a3 = _drag_gravity(v3, k, g)
    v4 = (v1[0] + h * a3[0], v1[1] + h * a3[1], v1[2] + h * a3[2])
    a4 = _drag_gravity(v4, k, g)
    w = h / 6.0
    return (
        *(y[i] + w * (v1[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]) for i in range(3)),
        *(y[3 + i] + w * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]) for i in range(3)),
    )


def _grid(y0: np.ndarray, t_end: float, k: float, g: float) -> np.ndarray:
    """States (M + 1, B, 6) at ``0, STEP, ..., M STEP`` with ``M STEP <= t_end``, from ``y0``
    (B, 6): :func:`_rk4` steps, one row at a time (:func:`_rk4_row`)."""
    n = int(math.floor(t_end / STEP + 1e-9))
    out = np.empty((n + 1, *y0.shape))
    for b, row in enumerate(y0.tolist()):
        y = tuple(row)
        states = [y]
        for _ in range(n):
            y = _rk4_row(y, STEP, k, g)
            states.append(y)
        out[:, b] = states
    return out


def _flight(y0: np.ndarray, t: float, k: float, g: float) -> np.ndarray:
    """States (B, 6) at time ``t`` >= 0 after release from ``y0`` (B, 6)."""
    nodes = _grid(y0, t, k, g)
    return _rk4(nodes[-1], t - (len(nodes) - 1) * STEP, k, g)


def solve_release_velocity(
    p_release: np.ndarray, target: np.ndarray, flight_time: float, drag: float, gravity: float
) -> np.ndarray:
    """Release velocity [m/s] (3,) that puts the ball at ``target`` (3,) after ``flight_time`` [s].

    Newton's method on the drag ODE (shooting), finite-difference Jacobian, from the drag-free
    solution; stops when the miss is below 1 um.

    Raises:
        NoSolutionError: no convergence in 30 iterations.
    """
    p0, target = np.asarray(p_release, float), np.asarray(target, float)
    v = (target - p0) / flight_time
    v[2] += 0.5 * gravity * flight_time
    eps = 1e-5
    for _ in range(30):
        y0 = np.tile(np.concatenate([p0, v]), (4, 1))
        y0[1:, 3:] += eps * np.eye(3)
        p = _flight(y0, flight_time, drag, gravity)[:, :3]
        miss = p[0] - target
        if np.linalg.norm(miss) < 1e-6:
            return v
        jac = (p[1:] - p[0]).T / eps
        v = v - np.linalg.solve(jac, miss)
    raise NoSolutionError(f"no release velocity from {p0} to {target} in {flight_time:g} s")


def make_throw(
    cfg: ThrowConfig,
    p_release: np.ndarray,
    aim: tuple[float, float],
    flight_time: float,
    t_release: float = 0.5,
    throw_id: str = "manual",
    hand: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> Throw:
    """A throw from ``p_release`` [m] (3,) to ``(cfg.plane_distance, *aim)`` in ``flight_time`` [s].

    ``hand`` is (amplitude [m], frequency [Hz], phase [rad]), each (3,); None holds the ball still.
    """
    target = np.array([cfg.plane_distance, aim[0], aim[1]])
    k = cfg.drag_k()
    v = solve_release_velocity(p_release, target, flight_time, k, cfg.gravity)
    amp, freq, phase = hand if hand is not None else (np.zeros(3), np.ones(3), np.zeros(3))
    return Throw(
        throw_id, float(t_release), _frozen(p_release), _frozen(v), k, _frozen(aim),
        float(flight_time), cfg.gravity, cfg.plane_distance, _frozen(amp), _frozen(freq),
        _frozen(phase),
    )  # fmt: skip


def sample_throws(cfg: ThrowConfig, n: int, seed: int, feints: int = 0) -> list[Throw]:
    """``n`` throws drawn from ``cfg``, then ``feints`` feints; each depends only on
    ``(cfg, seed, index)``.

    Throw ``i`` (id ``s<seed>-<i>``) draws its kind from ``cfg.thrower.mix`` after its release
    state, so an all-``still`` mix draws exactly the throws it always did. Feint ``j`` (id
    ``s<seed>-f<j>``) has a seed sequence of its own.
    """
    out = [
        _sample(cfg, ss, f"s{seed}-{i}", None)
        for i, ss in enumerate(np.random.SeedSequence(seed).spawn(n))
    ]
    for j in range(feints):
        ss = np.random.SeedSequence(seed, spawn_key=(FEINT_KEY, j))
        out.append(_sample(cfg, ss, f"s{seed}-f{j}", "feint"))
    return out


def _sample(cfg: ThrowConfig, ss: np.random.SeedSequence, throw_id: str, kind: str | None) -> Throw:
    rng = np.random.default_rng(ss)
    x, y, z, aim_y, aim_z, flight_time, hold = (
        rng.uniform(*r)
        for r in (cfg.release_distance, cfg.release_lateral, cfg.release_height, cfg.aim_y,
                  cfg.aim_z, cfg.flight_time, cfg.hold_time)
    )  # fmt: skip
    p, aim = np.array([cfg.plane_distance + x, y, z]), (aim_y, aim_z)
    hand = (
        cfg.hand_motion * rng.uniform(0.5, 1.0, 3),
        rng.uniform(*cfg.hand_frequency, 3),
        rng.uniform(0.0, 2.0 * math.pi, 3),
    )
    th = make_throw(cfg, p, aim, flight_time, hold, throw_id, hand)
    u = rng.random(DRAWS)
    return with_motion(cfg, th, kind or cfg.thrower.kind_of(u[0]), u)


def with_motion(cfg: ThrowConfig, throw: Throw, kind: str, u: np.ndarray) -> Throw:
    """``throw`` as a ``kind`` throw, its motion drawn from ``cfg.thrower`` with ``u``.

    Args:
        cfg: the ranges (``cfg.thrower``).
        throw: a still throw (its hold time stays; ``t_release`` grows by the swings).
        kind: ``"still"`` (returns ``throw``), ``"windup"`` or ``"feint"``.
        u: :data:`~thinkfast.sim.thrower.DRAWS` uniform numbers in [0, 1).
    """
    if kind == "still":
        return throw
    m = sample_motion(cfg.thrower, kind, u, throw.p_release, throw.v_release)
    m = {k: (_frozen(v) if isinstance(v, np.ndarray) else v if k == "kind" else float(v))
         for k, v in m.items()}  # fmt: skip
    t_release = throw.t_release + m["back_time"] + m["forward_time"]
    return throw._replace(t_release=float(t_release), **m)


def ball_states(throw: Throw, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True ball centre [m] (N, 3) and velocity [m/s] (N, 3) in base at ``times`` [s] (N,).

    Times are after release. Before release (``t < 0``) a still throw's ball is in the hand at
    the release point plus the hand motion ``A (sin(2 pi f t + phi) - sin(phi))``, which is zero
    at release; a wind-up's is swung (``thinkfast.sim.thrower.swing_states``); a feint's ball is
    never released.
    """
    t = np.atleast_1d(np.asarray(times, dtype=float))
    p, v = np.empty((len(t), 3)), np.empty((len(t), 3))
    hold = t < 0.0
    if throw.kind != "still":
        if throw.kind == "feint":
            hold[:] = True
        p[hold], v[hold] = swing_states(throw, t[hold])
    elif hold.any():
        w = 2.0 * math.pi * throw.hand_freq
        arg = w * t[hold, None] + throw.hand_phase
        p[hold] = throw.p_release + throw.hand_amp * (np.sin(arg) - np.sin(throw.hand_phase))
        v[hold] = throw.hand_amp * w * np.cos(arg)
    fly = ~hold
    if fly.any():
        y0 = np.concatenate([throw.p_release, throw.v_release])[None]
        nodes = _grid(y0, float(t[fly].max()), throw.drag, throw.gravity)[:, 0]
        idx = np.minimum(np.floor(t[fly] / STEP + 1e-9).astype(int), len(nodes) - 1)
        y = _rk4(nodes[idx], (t[fly] - idx * STEP)[:, None], throw.drag, throw.gravity)
        p[fly], v[fly] = y[:, :3], y[:, 3:]
    return p, v


def ball_state(throw: Throw, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Ball centre [m] (3,) and velocity [m/s] (3,) at ``t`` [s] after release."""
    p, v = ball_states(throw, np.array([t]))
    return p[0], v[0]


def ball_positions(throw: Throw, times: np.ndarray) -> np.ndarray:
    """Ball centres [m] (N, 3) in base at ``times`` [s after release] (N,)."""
    return ball_states(throw, times)[0]


def plane_crossing(throw: Throw, plane_x: float | None = None, t_max: float = 5.0) -> TrueCrossing:
    """When and where the ball centre crosses ``x = plane_x`` [m] (default: the throw's plane).

    Raises:
        NoSolutionError: the ball does not reach the plane within ``t_max`` [s], or the throw is
            a feint (never released).
    """
    if throw.kind == "feint":
        raise NoSolutionError(f"throw {throw.id} is a feint: it is never released")
    plane_x = throw.plane_x if plane_x is None else float(plane_x)
    y, i = (*throw.p_release.tolist(), *throw.v_release.tolist()), 0
    if y[0] <= plane_x:
        return TrueCrossing(0.0, y[1], y[2], throw.v_release.copy())
    while y[0] > plane_x:
        if i * STEP > t_max:
            raise NoSolutionError(
                f"throw {throw.id} does not reach x = {plane_x:g} m in {t_max:g} s"
            )
        prev, y, i = y, _rk4_row(y, STEP, throw.drag, throw.gravity), i + 1
    s = (prev[0] - plane_x) / -prev[3]
    for _ in range(8):  # Newton on x(s) along the partial step from the node before; x' = vx
        y = _rk4_row(prev, s, throw.drag, throw.gravity)
        s -= (y[0] - plane_x) / y[3]
    y = _rk4_row(prev, s, throw.drag, throw.gravity)
    return TrueCrossing((i - 1) * STEP + s, float(y[1]), float(y[2]), np.array(y[3:]))


def observed_until(throw: Throw, after_crossing: float) -> float:
    """When there is nothing more to see of ``throw`` [s after release]: ``after_crossing`` [s]
    after its centre crosses its plane; a feint's: the end of its rest."""
    if throw.kind == "feint":
        return float(throw.rest_time)
    return plane_crossing(throw).t + after_crossing
