"""The early, wide belief: where a ball that has just left the hold will cross the plane.

Before the launch detector (:mod:`thinkfast.estimate.launch`) confirms, the first flight
detections say where the ball is but little about its approach speed. They are combined with a
prior over the throws the cell expects (``[early]``: a crossing inside the goal grid's box, a
flight time range) that, from the ball's position, is a velocity prior (:func:`velocity_prior`).
The weighted least-squares flight fit with that prior (:func:`fit_with_prior`) has a mean and a
covariance from a single detection on; its plane crossing N(Y, Z, tau) is what the hedge stage
decides on. :func:`flight_run` picks the detections that left the hold and
:func:`likely_launch` is the hedge stage's trigger. Units: m, s, in ``base``.

The prior, the flight run with several cameras and the trigger: docs/DESIGN.md, "The early
belief".
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
    depart_lateral: float = spec(
        3.0,
        unit="sigma",
        lo=0.0,
        doc="a flight detection has also left the hold when its Mahalanobis distance from it "
        "(its noise and the hand's allowance) is this many stds (0: only the approach counts)",
    )
    hand_motion: float = spec(
        0.01,
        unit="m",
        lo=0.0,
        doc="ASSUMED: a held ball's own motion (tremor, drift over a few frames), added on "
        "every axis to the noise of the depart_lateral test",
    )
    trigger_points: int = spec(
        2, lo=1, hi=6, doc="detections of the flight run that must have left the hold (launch "
        "likely; with one camera the newest ones)",
    )  # fmt: skip
    max_points: int = spec(5, lo=1, hi=12, doc="newest flight detections the early fit uses")
    min_hold: int = spec(5, lo=1, doc="detections before the flight needed to locate the hold")
    alpha: float = spec(
        0.001, lo=1e-9, hi=0.5, doc="false-rejection rate of the fit's chi-square test"
    )
    max_drop: int = spec(
        1,
        lo=0,
        hi=1,
        doc="gross outliers the early fit may leave out (of 3 or more points; one is when "
        "leaving it out lowers the chi-square by more than the 3-dof 1 - alpha quantile)",
    )
    prior_age: bool = spec(
        False,
        doc="the prior's flight time counts from the flight run's first detection (the ball "
        "has flown that long already), not from the newest",
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
        left: detections of the flight run that have left the hold (not counting one the fit
            left out as an outlier).
    """

    t: float
    mean: np.ndarray
    cov: np.ndarray
    chi2: float
    n: int
    hold: np.ndarray
    left: int = 0


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
    """How many of the newest ``points`` (stamp, position (3,), noise covariance (3, 3)[, camera
    id]), oldest first, are the flight run (module doc: with one camera, the newest that have
    left the hold towards the plane), and the hold position (None: fewer than ``min_hold``
    detections before them, the hold is not known)."""
    n, k = len(points), _run(points, cfg)[0]
    if k > 0 or n >= cfg.min_hold:
        return k, np.median(np.array([p[1] for p in points[: n - k]]), axis=0)
    return 0, None


def _run(points: list, cfg: EarlyConfig) -> tuple[int, list[bool]]:
    """The length of :func:`flight_run`'s run (0: none) and, per detection of it, whether it
    has left the hold."""
    n = len(points)
    xs = [float(p[1][0]) for p in points]
    gap = [cfg.depart_sigmas * math.sqrt(p[2][0, 0]) for p in points]  # to leave the hold
    cams = [p[3] if len(p) > 3 else None for p in points]
    side = _Lateral(points, cfg) if cfg.depart_lateral > 0.0 else None
    for k in range(n - cfg.min_hold, 0, -1):  # the longest run first: a flight is a few points
        # the hold: the median of the detections before the run (as np.median), per axis
        hold_x = _median(sorted(xs[: n - k]))
        across = None if side is None else side.flags(n - k)
        flags = _left(xs[n - k :], gap[n - k :], cams[n - k :], hold_x, across)
        if flags is not None:
            return k, flags
    return 0, []


class _Lateral:
    """The second departure test of :func:`_run` (``depart_lateral`` > 0): a detection has left
    the hold when ``d^T (C + h^2 I)^-1 d > depart_lateral^2`` for its offset ``d`` from the
    hold's median, its noise ``C`` (3, 3) and the hand's allowance ``h`` (``hand_motion``),
    it is nearer the plane than the hold, and the ``min_hold`` detections before it were all
    that close to the hold (a still hold). Across the camera's viewing ray the noise is
    millimetres, along it decimetres: a throw's rise and sideways motion show a frame or two
    before its approach does. A wind-up's back swing goes away from the plane."""

    def __init__(self, points: list, cfg: EarlyConfig):
        self.pos = np.array([p[1] for p in points], dtype=float).reshape(-1, 3)
        h2 = cfg.hand_motion * cfg.hand_motion
        covs = np.array([p[2] for p in points], dtype=float).reshape(-1, 3, 3) + h2 * np.eye(3)
        self.info = inv(covs) if len(points) else covs
        self.limit = cfg.depart_lateral * cfg.depart_lateral
        self.still = cfg.min_hold

    def flags(self, start: int) -> list[bool]:
        """Per detection from ``start`` on, whether it left the hold of the ones before."""
        hold = np.median(self.pos[:start], axis=0)
        d = self.pos - hold
        d2 = np.einsum("ni,nij,nj->n", d, self.info, d)
        if np.any(d2[max(start - self.still, 0) : start] > self.limit):
            return [False] * (len(d2) - start)  # the ball was moving: no still hold to leave
        d, d2 = d[start:], d2[start:]
        return [bool(q > self.limit) and float(e[0]) < 0.0 for q, e in zip(d2, d, strict=True)]


def _left(
    xs: list, gaps: list, cams: list, hold_x: float, across: list | None = None
) -> list[bool] | None:
    """Per detection (x [m], gap to leave the hold [m], camera), whether it left the hold at
    ``hold_x`` [m] (towards the plane, or across it where ``across`` says so); None when they
    are no flight run: the first has not left, or a camera's detection that has not left comes
    after one of that camera's that has."""
    flags: list[bool] = []
    gone = set()  # cameras that have shown the ball leave
    for i, (x, g, cam) in enumerate(zip(xs, gaps, cams, strict=True)):
        left = hold_x - x > g or (across is not None and across[i])
        if left:
            gone.add(cam)
        elif not flags or cam in gone:
            return None
        flags.append(left)
    return flags


def _median(v: list[float]) -> float:
    """``np.median`` of sorted floats: the middle one, or the mean of the middle two."""
    h = len(v) // 2
    return v[h] if len(v) % 2 else (v[h - 1] + v[h]) / 2.0


def early_fit(
    points: list, cfg: EarlyConfig, plane_x: float, yz_lo, yz_hi, gravity: float
) -> EarlyFit | None:
    """The early belief from the flight run among ``points`` (see :func:`flight_run`; its
    ``max_points`` newest, one gross outlier left out with ``max_drop``), or None when no
    detection has left a known hold."""
    k, flags = _run(points, cfg)
    if k == 0:
        return None
    hold = np.median(np.array([p[1] for p in points[: len(points) - k]]), axis=0)
    t_first = float(points[len(points) - k][0])  # the run's first detection [s]
    m = min(k, cfg.max_points)
    run = points[-m:]
    lo = np.asarray(yz_lo, dtype=float) - cfg.region_margin
    hi = np.asarray(yz_hi, dtype=float) + cfg.region_margin
    penalty = chi2_limit(cfg.alpha, 3)  # what leaving one point out must gain
    best, score = None, math.inf
    for out in [None, *(range(m) if cfg.max_drop and m >= 3 else ())]:
        sub = run if out is None else run[:out] + run[out + 1 :]
        times = np.array([p[0] for p in sub])
        pts = np.array([p[1] for p in sub])
        covs = np.array([p[2] for p in sub])
        tau = _flight_time(cfg, float(times[-1]) - t_first)
        vm, vc = velocity_prior(pts[-1], plane_x, lo, hi, tau, gravity, cfg.grid)
        x, cov, c2 = fit_with_prior(times, pts, covs, gravity, vm, vc)
        cost = c2 if out is None else c2 + penalty
        if cost < score:
            score = cost
            left = sum(flags) - (out is not None and flags[k - m + out])
            best = EarlyFit(float(times[-1]), x, cov, c2, len(sub), hold, left)
    return best


def likely_launch(fit: EarlyFit | None, cfg: EarlyConfig) -> bool:
    """The hedge trigger: ``trigger_points`` detections of the flight run left the hold, and
    the fit explains its detections by a free flight at the prior's speeds (chi-square of the
    3 n residuals and the 3 prior terms, 6 fitted)."""
    if fit is None or fit.left < cfg.trigger_points:
        return False
    return fit.chi2 <= chi2_limit(cfg.alpha, max(3 * fit.n - 3, 1))


def _flight_time(cfg: EarlyConfig, age: float) -> tuple[float, float]:
    """The prior's flight time [s] (lo, hi) from a detection ``age`` [s] after the run's first
    (with ``prior_age``: the ball has flown at least that long; never below 50 ms)."""
    if not cfg.prior_age:
        return cfg.flight_time
    lo, hi = cfg.flight_time
    return max(lo - age, 0.05), max(hi - age, 0.1)
