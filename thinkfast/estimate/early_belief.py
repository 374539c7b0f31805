"""The early, wide belief: where a ball that has just left the hold will cross the plane.

The launch detector (:mod:`thinkfast.estimate.launch`) declares a launch only once two windows
of at least four detections fit a free flight, some frames after the first flight detection is
delivered (docs/RESULTS.md, "Feints, held balls, starts before release"). Before that, the first
one to three detections that left the hold already say a little: where the ball is, roughly how
fast it moves laterally. Alone they say almost nothing
about the approach speed (the stereo depth noise at 6-8 m is 8-19 cm per frame, the ball moves
17-35 cm per frame), so they are combined with a **prior over the throws the cell expects**
(``[early]``): the ball crosses the plane inside the goal grid's box widened by
``region_margin``, ``flight_time`` after leaving (uniform on both). From the ball's position
``p`` that prior is a distribution of its velocity: ``v = (C - p + g tau^2 / 2 e_z) / tau`` for
a crossing point ``C`` and remaining flight time ``tau``; its mean and covariance come from the
moments over a ``grid`` ^ 3 lattice of (Y, Z, tau) (:func:`velocity_prior`).

The early belief is the weighted least-squares free flight through the flight detections (the
launch detector's noise model) with that velocity prior as one more measurement
(:func:`fit_with_prior`, information form): from a single detection on it has a mean and a
covariance, and each detection narrows it. Its plane crossing (the delta method,
:mod:`thinkfast.estimate.crossing`) is the N(Y, Z, tau) the hedge stage decides on.

Which detections are flight (:func:`flight_run`): the newest ones, each nearer the plane than the
hold by ``depart_sigmas`` of its depth noise; the hold is the median of the detections before
them (at least ``min_hold`` of them: a ball first seen in flight has no hold to leave). A
*launch is likely* (:func:`likely_launch`) when the ``trigger_points`` newest detections have
left the hold and the flight fit with the prior explains them (chi-square below its ``1 -
alpha`` quantile): a ball moved by the hand at under a metre per second against a prior of 8 m/s
or more does not. This is the hedge stage's trigger; the launch detector still confirms.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.estimate.chi2 import chi2_limit
from thinkfast.estimate.linalg import inv


@dataclasses.dataclass(frozen=True)
class EarlyConfig:
    """Early belief and launch-likely test (``[early]`` table of the runtime configuration)."""

    flight_time: tuple[float, float] = spec(
        (0.4, 0.8),
        unit="s",
        length=2,
        lo=0.05,
        doc="ASSUMED prior: flight time from the hand to the plane, uniform between the two "
        "(the thrower's throws, docs/FACTS.md)",
    )
    region_margin: float = spec(
        0.3,
        unit="m",
        lo=0.0,
        doc="ASSUMED prior: the crossing lies uniformly in the goal grid's box widened by this",
    )
    grid: int = spec(5, lo=2, hi=15, doc="lattice points per axis of the prior's moments")
    depart_sigmas: float = spec(
        2.0,
        unit="sigma",
        lo=0.0,
        doc="a flight detection is nearer the plane than the hold by this many depth stds",
    )
    trigger_points: int = spec(
        2, lo=1, hi=6, doc="newest detections that must have left the hold (launch likely)"
    )
    max_points: int = spec(5, lo=1, hi=12, doc="newest flight detections the early fit uses")
    min_hold: int = spec(5, lo=1, doc="detections before the flight needed to locate the hold")
    alpha: float = spec(
        0.001, lo=1e-9, hi=0.5, doc="false-rejection rate of the fit's chi-square test"
    )


class EarlyFit(NamedTuple):
    """The early belief at the newest flight detection.

    Attributes:
        t: its stamp [s].
        mean: [X Y Z Vx Vy Vz] in base at ``t`` [m, m/s], shape (6,).
        cov: covariance, shape (6, 6).
        chi2: residual chi-square of the detections and the prior.
        n: flight detections used.
        hold: the hold position [m], shape (3,).
    """

    t: float
    mean: np.ndarray
    cov: np.ndarray
    chi2: float
    n: int
    hold: np.ndarray


def velocity_prior(
    p: np.ndarray, plane_x: float, yz_lo, yz_hi, tau, gravity: float, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Mean (3,) [m/s] and covariance (3, 3) of the velocity of a ball at ``p`` [m] (3,) that
    crosses the plane ``x = plane_x`` uniformly inside the box ``yz_lo``..``yz_hi`` [m] (2,)
    after a time uniform in ``tau`` [s] (2,): moments over an ``n``^3 lattice of cell centres."""
    yy, zz, tt, fall = _lattice(*map(float, (*yz_lo, *yz_hi, *tau, gravity)), n)
    v = np.empty((len(tt), 3))  # the columns as np.stack lays them out
    np.divide(plane_x - p[0], tt, out=v[:, 0])
    np.divide(yy - p[1], tt, out=v[:, 1])
    np.divide(zz - p[2] + fall, tt, out=v[:, 2])
    mean = v.mean(axis=0)
    d = v - mean
    return mean, d.T @ d / len(v)


@functools.lru_cache(maxsize=8)
def _lattice(y0, z0, y1, z1, t0, t1, gravity, n) -> tuple[np.ndarray, ...]:
    """The ``n``^3 lattice of :func:`velocity_prior` (crossing y, z [m], time tau [s], each
    (n^3,)) and the fall ``0.5 g tau^2`` [m] there (read-only, cached: one prior per cell)."""
    u = (np.arange(n) + 0.5) / n
    y = y0 + u * (y1 - y0)
    z = z0 + u * (z1 - z0)
    t = t0 + u * (t1 - t0)
    yy, zz, tt = (a.ravel() for a in np.meshgrid(y, z, t, indexing="ij"))
    out = (yy, zz, tt, 0.5 * gravity * tt * tt)
    for a in out:
        a.setflags(write=False)
    return out


def fit_with_prior(
    times: np.ndarray,
    points: np.ndarray,
    covs: np.ndarray,
    gravity: float,
    v_mean: np.ndarray,
    v_cov: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Free flight through ``points`` [m] (N, 3) seen at ``times`` [s] (N,) with noise
    ``covs`` [m^2] (N, 3, 3), with the prior N(``v_mean``, ``v_cov``) on the velocity [m/s].

    Returns:
        (mean (6,), covariance (6, 6), chi-square of the residuals and the prior), the state
        at ``times[-1]``. Defined from one point on.
    """
    dt = np.asarray(times, dtype=float) - float(times[-1])
    w = inv(covs)
    y = np.array(points, dtype=float)
    y[:, 2] += 0.5 * gravity * dt * dt  # remove the known gravity term
    wp = inv(v_cov)
    info = np.zeros((6, 6))
    info[:3, :3] = w.sum(axis=0)
    info[:3, 3:] = info[3:, :3] = np.einsum("n,nij->ij", dt, w)
    info[3:, 3:] = np.einsum("n,nij->ij", dt * dt, w) + wp
    wy = np.einsum("nij,nj->ni", w, y)
    rhs = np.r_[wy.sum(axis=0), dt @ wy + wp @ v_mean]
    cov = inv(info)
    cov = 0.5 * (cov + cov.T)
    x = cov @ rhs
    res = y - (x[:3] + dt[:, None] * x[3:])
    dv = x[3:] - v_mean
    c2 = float(np.einsum("ni,nij,nj->", res, w, res) + dv @ wp @ dv)
    return x, cov, c2


def flight_run(points: list, cfg: EarlyConfig) -> tuple[int, np.ndarray | None]:
    """How many of the newest ``points`` (stamp, position (3,), noise covariance (3, 3)), oldest
    first, have left the hold towards the plane, and the hold position (None: fewer than
    ``min_hold`` detections before them, the hold is not known)."""
    n, k = len(points), _run(points, cfg)
    if k > 0 or n >= cfg.min_hold:
        return k, np.median(np.array([p[1] for p in points[: n - k]]), axis=0)
    return 0, None


def _run(points: list, cfg: EarlyConfig) -> int:
    """The length of :func:`flight_run`'s run (0: none)."""
    n = len(points)
    xs = [float(p[1][0]) for p in points]
    gap = [cfg.depart_sigmas * math.sqrt(p[2][0, 0]) for p in points]  # to leave the hold
    for k in range(n - cfg.min_hold, 0, -1):  # the longest run first: a flight is a few points
        # only the hold's x decides: the median of the x before the run (as np.median)
        hold_x = _median(sorted(xs[: n - k]))
        if all(hold_x - x > g for x, g in zip(xs[n - k :], gap[n - k :], strict=True)):
            return k
    return 0


def _median(v: list[float]) -> float:
    """``np.median`` of sorted floats: the middle one, or the mean of the middle two."""
    h = len(v) // 2
    return v[h] if len(v) % 2 else (v[h - 1] + v[h]) / 2.0


def early_fit(
    points: list, cfg: EarlyConfig, plane_x: float, yz_lo, yz_hi, gravity: float
) -> EarlyFit | None:
    """The early belief from the flight detections among ``points`` (see :func:`flight_run`;
    the ``max_points`` newest), or None when none has left a known hold."""
    k = _run(points, cfg)
    if k == 0:
        return None
    hold = np.median(np.array([p[1] for p in points[: len(points) - k]]), axis=0)
    run = points[-min(k, cfg.max_points) :]
    times = np.array([p[0] for p in run])
    pts = np.array([p[1] for p in run])
    covs = np.array([p[2] for p in run])
    lo = np.asarray(yz_lo, dtype=float) - cfg.region_margin
    hi = np.asarray(yz_hi, dtype=float) + cfg.region_margin
    vm, vc = velocity_prior(pts[-1], plane_x, lo, hi, cfg.flight_time, gravity, cfg.grid)
    x, cov, c2 = fit_with_prior(times, pts, covs, gravity, vm, vc)
    return EarlyFit(float(times[-1]), x, cov, c2, len(run), hold)


def likely_launch(fit: EarlyFit | None, cfg: EarlyConfig) -> bool:
    """The hedge trigger: ``trigger_points`` flight detections, explained by a free flight at the
    prior's speeds (chi-square of the 3 n residuals and the 3 prior terms, 6 fitted)."""
    if fit is None or fit.n < cfg.trigger_points:
        return False
    return fit.chi2 <= chi2_limit(cfg.alpha, max(3 * fit.n - 3, 1))
