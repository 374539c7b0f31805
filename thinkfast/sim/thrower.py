"""The thrower's hand before the release: still, wind-up and feint motions of the ball.

Three kinds of throw (:data:`KINDS`); time ``t`` is measured from the release (negative before):

* ``still``: the ball is held still (small hand motion) and released (the original model);
* ``windup``: held still (same hand motion), then a *back swing* (the ball moves ``back_swing``
  along a slightly curved path, back and down, minimum-jerk timing: rest to rest), then a
  *forward swing* in a straight line along ``forward_swing`` (parallel to the release velocity)
  that accelerates from rest to the release velocity and ends at the release point: speed
  ``|v_release| Phi(u)``, ``u`` the fraction of the swing's time, with ``Phi`` the CDF of a blend
  ``(1 - w) Beta(2, 4) + w Beta(4, 2)`` of acceleration profiles (zero acceleration at both ends;
  ``w`` follows from the swing's travel: its mean speed is ``(2 - w) / 3`` of the release speed);
* ``feint``: held, back swing, then a forward swing that stops (minimum-jerk, rest to rest, its
  peak speed a fraction of the feigned throw's release speed); the ball stays still at
  ``p_release`` (the point where it stopped) from ``t = 0`` for ``rest_time``; no release.

Position is continuous everywhere and velocity too (acceleration as well, but at the release).
The hand motion of the hold, ``A (sin(2 pi f s + phi) - sin(phi))`` with ``s`` the time since
the hold began to end, fades out over the back swing with the same minimum-jerk weight.
Everything here is a pure function of time; ``thinkfast.sim.throws.ball_states`` calls it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from numpy.polynomial import polynomial as P

from thinkfast.config import spec
from thinkfast.errors import ConfigError, NoSolutionError

KINDS = ("still", "windup", "feint")
DEFAULT_MIX = (0.5, 0.5, 0.0)
"""Default weights of (still, windup, feint). Switching the default mix is this one line."""
STILL_MIX = (1.0, 0.0, 0.0)
"""Every throw a still hold: the simulator before the thrower model (version 1 throw sets)."""
MINJERK_PEAK = 1.875
"""Peak speed of a minimum-jerk rest-to-rest move over its mean speed."""
DRAWS = 9
"""Uniform numbers each sampled throw draws for its kind and motion (after the release draws)."""


def _rng(doc: str, default: tuple[float, float], unit: str, lo: float = 0.0, **kw: Any) -> Any:
    return spec(
        default, doc=f"{doc} (uniform between the two values)", unit=unit, lo=lo, length=2, **kw
    )


@dataclasses.dataclass(frozen=True)
class ThrowerConfig:
    """The thrower's motions before the release (the ``thrower`` table of a throw config).

    Every range is ASSUMED: chosen as plausible for an adult's overarm throw of a tennis ball
    (a 0.2-0.4 m back swing, a 0.1-0.2 s, ~1 m forward acceleration), not measured on real
    throwers. The draw picks the forward swing's time and
    travel inside their ranges such that the mean speed stays inside ``forward_mean_speed``.
    """

    mix: tuple[float, float, float] = spec(
        DEFAULT_MIX, doc="relative weights of still, windup, feint throws in a drawn set",
        length=3, lo=0.0,
    )  # fmt: skip
    back_distance: tuple[float, float] = _rng("back swing length, ASSUMED", (0.2, 0.4), "m")
    back_time: tuple[float, float] = _rng("back swing duration, ASSUMED", (0.2, 0.4), "s", 0.05)
    back_drop: tuple[float, float] = _rng(
        "back swing angle below the horizontal, ASSUMED", (0.1, 0.5), "rad", hi=1.2
    )
    back_sag: tuple[float, float] = _rng(
        "back swing arc: path below its chord at mid swing, ASSUMED", (0.0, 0.05), "m"
    )
    forward_distance: tuple[float, float] = _rng(
        "forward swing travel to the release, ASSUMED", (0.8, 1.2), "m", 0.05
    )
    forward_time: tuple[float, float] = _rng(
        "forward swing duration, ASSUMED", (0.1, 0.2), "s", 0.02
    )
    forward_mean_speed: tuple[float, float] = _rng(
        "forward swing mean speed over the release speed (0.5: acceleration peaks mid swing, "
        "lower: later), ASSUMED", (0.4, 0.6), "-", 1.0 / 3.0, hi=2.0 / 3.0,
    )  # fmt: skip
    feint_peak_speed: tuple[float, float] = _rng(
        "feint: peak speed over the feigned throw's release speed, ASSUMED", (0.2, 0.6), "-",
        hi=1.0,
    )  # fmt: skip
    feint_time: tuple[float, float] = _rng(
        "feint: duration of the aborted forward swing, ASSUMED", (0.15, 0.3), "s", 0.02
    )
    feint_rest: tuple[float, float] = _rng(
        "feint: ball held still (and seen) after it stops, ASSUMED", (2.0, 3.0), "s"
    )

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if len(v) == 2 and v[0] > v[1]:
                raise ConfigError(
                    "throw config", f"thrower.{f.name}", f"low {v[0]:g} > high {v[1]:g}"
                )
        if sum(self.mix) <= 0.0:
            raise ConfigError("throw config", "thrower.mix", "weights must not all be 0")

    def kind_of(self, u: float) -> str:
        """The kind a uniform number ``u`` in [0, 1) draws from :attr:`mix`."""
        edges = np.cumsum(self.mix) / sum(self.mix)
        return KINDS[min(int(np.searchsorted(edges, u, side="right")), len(KINDS) - 1)]


def parse_mix(text: str, source: str = "--mix") -> tuple[float, float, float]:
    """``"still=0.5,windup=0.5"`` -> weights of (still, windup, feint); missing kinds weigh 0.

    Raises:
        ConfigError: unknown kind, bad number, negative weight or all weights 0.
    """
    w = dict.fromkeys(KINDS, 0.0)
    for item in (x.strip() for x in text.split(",") if x.strip()):
        name, _, value = (x.strip() for x in item.partition("="))
        if name not in w:
            raise ConfigError(source, None, f"{name!r} is not one of {', '.join(KINDS)}")
        try:
            w[name] = float(value)
        except ValueError:
            raise ConfigError(source, None, f"{item!r}: expected KIND=WEIGHT") from None
        if not (w[name] >= 0.0 and math.isfinite(w[name])):
            raise ConfigError(source, None, f"{item!r}: weight must be a number >= 0")
    if sum(w.values()) <= 0.0:
        raise ConfigError(source, None, f"{text!r}: give at least one positive weight")
    return (w["still"], w["windup"], w["feint"])


def _in(u: float, lo: float, hi: float) -> float:
    return lo + u * (hi - lo)


def sample_motion(
    cfg: ThrowerConfig, kind: str, u: np.ndarray, p_release: np.ndarray, v_release: np.ndarray
) -> dict[str, Any]:
    """The motion fields of a :class:`~thinkfast.sim.throws.Throw` of ``kind``.

    Args:
        cfg: ranges.
        kind: one of :data:`KINDS`.
        u: :data:`DRAWS` uniform numbers in [0, 1) (``u[0]`` drew the kind and is not used).
        p_release, v_release: release state of the throw (for a feint: of the feigned throw)
            [m], [m/s], (3,) each.

    Returns:
        Keyword arguments for ``Throw._replace``: ``kind``, ``back_time``, ``back_swing``,
        ``back_sag``, ``forward_time``, ``forward_swing``, ``rest_time`` and, for a feint,
        ``p_release`` (where the ball stops) and ``v_release`` (zero).

    Raises:
        NoSolutionError: no forward swing time and travel inside their ranges gives a mean speed
            inside ``forward_mean_speed`` for this release speed.
    """
    if kind == "still":
        return {"kind": "still"}
    speed = float(np.linalg.norm(v_release))
    d = v_release / speed
    horiz = np.array([d[0], d[1], 0.0])
    back_dir = -horiz / max(float(np.linalg.norm(horiz)), 1e-9)  # away from the target
    drop = _in(u[3], *cfg.back_drop)
    e = math.cos(drop) * back_dir + math.sin(drop) * np.array([0.0, 0.0, -1.0])
    below = np.array([0.0, 0.0, -1.0]) - math.sin(drop) * e  # down, perpendicular to e
    out: dict[str, Any] = {
        "kind": kind,
        "back_time": _in(u[2], *cfg.back_time),
        "back_swing": _in(u[1], *cfg.back_distance) * e,
        "back_sag": _in(u[4], *cfg.back_sag) * below / np.linalg.norm(below),
    }
    if kind == "windup":
        t_f, travel = _forward_time_travel(cfg, speed, u[5], u[6])
        out.update(forward_time=t_f, forward_swing=travel * d, rest_time=0.0)
        return out
    start = p_release - _in(u[6], *cfg.forward_distance) * d  # where a throw's swing would start
    t_f = _in(u[5], *cfg.feint_time)
    travel = _in(u[7], *cfg.feint_peak_speed) * speed * t_f / MINJERK_PEAK
    out.update(
        forward_time=t_f, forward_swing=travel * d, rest_time=_in(u[8], *cfg.feint_rest),
        p_release=start + travel * d, v_release=np.zeros(3),
    )  # fmt: skip
    return out


def _forward_time_travel(
    cfg: ThrowerConfig, speed: float, u_t: float, u_l: float
) -> tuple[float, float]:
    """Forward swing duration [s] and travel [m] inside their ranges, mean speed in range."""
    (t0, t1), (l0, l1), (c0, c1) = cfg.forward_time, cfg.forward_distance, cfg.forward_mean_speed
    lo, hi = max(t0, l0 / (c1 * speed)), min(t1, l1 / (c0 * speed))
    if lo > hi:
        raise NoSolutionError(
            f"thrower: no forward swing for a {speed:.1f} m/s release inside forward_time, "
            "forward_distance and forward_mean_speed"
        )
    t_f = _in(u_t, lo, hi)
    return t_f, _in(u_l, max(l0, c0 * speed * t_f), min(l1, c1 * speed * t_f))


def _beta_polys() -> tuple[np.ndarray, ...]:
    """CDF and its integral of Beta(2, 4) and Beta(4, 2) as polynomial coefficients."""
    out = []
    for dens in (20.0 * P.polymul([0, 1], P.polypow([1, -1], 3)),
                 20.0 * P.polymul(P.polypow([0, 1], 3), [1, -1])):  # fmt: skip
        cdf = P.polyint(dens)
        out += [cdf, P.polyint(cdf)]
    return tuple(out)


_CDF_A, _INT_A, _CDF_B, _INT_B = _beta_polys()


def forward_blend(throw: Any) -> float:
    """Weight ``w`` of Beta(4, 2) in a wind-up's acceleration profile, from its travel."""
    speed = float(np.linalg.norm(throw.v_release))
    mean = float(np.linalg.norm(throw.forward_swing)) / (speed * throw.forward_time)
    return 2.0 - 3.0 * mean


def _minjerk(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-jerk fraction of a rest-to-rest move and its derivative in ``u``."""
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2), 30.0 * u**2 * (1.0 - u) ** 2


def swing_states(throw: Any, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ball centre [m] (N, 3) and velocity [m/s] (N, 3) of a wind-up or feint at ``t`` (N,).

    ``t`` [s after release] must be < 0 for a wind-up (its flight is the drag ODE's); a feint's
    ball is still at ``p_release`` from ``t = 0`` on.
    """
    t = np.asarray(t, dtype=float)
    t_f0 = -throw.forward_time
    t_b0 = t_f0 - throw.back_time
    f0 = throw.p_release - throw.forward_swing  # forward swing start
    hold = f0 - throw.back_swing
    p, v = np.empty((len(t), 3)), np.empty((len(t), 3))

    w = 2.0 * math.pi * throw.hand_freq
    arg = w * (t - t_b0)[:, None] + throw.hand_phase
    tremor = throw.hand_amp * (np.sin(arg) - np.sin(throw.hand_phase))
    tremor_v = throw.hand_amp * w * np.cos(arg)

    m = t < t_b0
    p[m], v[m] = hold + tremor[m], tremor_v[m]
    m = (t >= t_b0) & (t < t_f0)
    s, ds = _minjerk((t[m] - t_b0) / throw.back_time)
    s, ds = s[:, None], ds[:, None] / throw.back_time
    arc = 4.0 * s * (1.0 - s)
    p[m] = hold + s * throw.back_swing + arc * throw.back_sag + (1.0 - s) * tremor[m]
    v[m] = ds * (throw.back_swing + 4.0 * (1.0 - 2.0 * s) * throw.back_sag - tremor[m])
    v[m] += (1.0 - s) * tremor_v[m]
    m = (t >= t_f0) & (t < 0.0)
    u = (t[m] - t_f0) / throw.forward_time
    if throw.kind == "windup":
        speed = float(np.linalg.norm(throw.v_release))
        d = throw.forward_swing / np.linalg.norm(throw.forward_swing)
        b = forward_blend(throw)
        cdf = (1.0 - b) * P.polyval(u, _CDF_A) + b * P.polyval(u, _CDF_B)
        dist = (1.0 - b) * P.polyval(u, _INT_A) + b * P.polyval(u, _INT_B)
        p[m] = f0 + (speed * throw.forward_time * dist)[:, None] * d
        v[m] = (speed * cdf)[:, None] * d
    else:
        s, ds = _minjerk(u)
        p[m] = f0 + s[:, None] * throw.forward_swing
        v[m] = (ds / throw.forward_time)[:, None] * throw.forward_swing
    m = t >= 0.0
    p[m], v[m] = throw.p_release, 0.0
    return p, v


def check_motion(throw: Any) -> str | None:
    """Why a throw's recorded motion is impossible, or None (for reading throw-set files)."""
    if throw.kind not in KINDS:
        return f"kind {throw.kind!r} is not one of {', '.join(KINDS)}"
    if throw.kind == "still":
        return None
    if not (throw.back_time > 0.0 and throw.forward_time > 0.0):
        return "back_time and forward_time must be > 0"
    if throw.kind == "windup":
        if not 0.0 < float(np.linalg.norm(throw.forward_swing)):
            return "a wind-up needs a forward swing"
        if not -1e-9 <= forward_blend(throw) <= 1.0 + 1e-9:
            return "forward swing mean speed must be 1/3 to 2/3 of the release speed"
    elif throw.rest_time < 0.0 or np.any(throw.v_release != 0.0):
        return "a feint has rest_time >= 0 and v_release 0"
    return None
