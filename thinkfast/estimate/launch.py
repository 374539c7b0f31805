"""Launch detection: has the ball just left the hand towards the plane?

The ball filter (:mod:`thinkfast.estimate.filter`) converges on a ball at rest during the hold
and follows the flight only slowly after the release; the arm cannot wait for it. This detector
fits a free flight (constant velocity, gravity known) by weighted least squares to the newest
detections, robust to up to ``max_drop`` gross outliers, and declares a launch when ``confirm``
windows in a row fit their points, approach the plane faster than ``min_speed`` and have left
the hold. Units: m, s, m/s, in ``base``.

The fit (state and covariance at the newest stamp) then restarts the filter.

The model, the tests a window must pass and why two windows are needed: docs/DESIGN.md,
"Launch detection".
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections import deque
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.estimate.chi2 import chi2_limit
from thinkfast.estimate.filter import FilterConfig, stereo_r


@dataclasses.dataclass(frozen=True)
class LaunchConfig:
    """Launch detector parameters (``[launch]`` table of the runtime configuration)."""

    enabled: bool = spec(True, doc="detect the launch from a short free-flight fit")
    window: int = spec(
        6,
        lo=4,
        hi=12,
        doc="detections per fit (the newest ones), at 50 fps: the default camera at another "
        "[camera] fps keeps the same time span (VGA at 100 fps: 11)",
    )
    check_hold: bool = spec(
        True, doc="the newest detection must have left the hold position (see the module doc)"
    )
    check_without_newest: bool = spec(
        True, doc="the window without its newest point must pass too (one point never decides)"
    )
    max_drop: int = spec(
        2,
        lo=0,
        hi=3,
        doc="gross outliers a window may hold (a point is one when leaving it out lowers the "
        "residual chi-square by more than its 1 - alpha quantile with 3 degrees of freedom)",
    )
    confirm: int = spec(2, lo=1, hi=5, doc="consecutive passing fits that declare a launch")
    max_span: float = spec(
        0.12, unit="s", lo=0.0, lo_open=True, doc="longest time a window may cover (dropouts)"
    )
    alpha: float = spec(
        0.001, lo=1e-9, hi=0.5, doc="false-rejection rate of the residual chi-square test"
    )
    min_speed: float = spec(
        3.0,
        unit="m/s",
        lo=0.0,
        doc="approach speed a launch must exceed with confidence (throws of 6-8 m in 0.4-0.8 s "
        "leave the hand at 8.5 m/s or more, docs/FACTS.md; a hand moves the ball at under 1 m/s)",
    )
    sigmas: float = spec(
        2.0, unit="sigma", lo=0.0, doc="confidence of the approach-speed test (2: ~98 %)"
    )
    noise_scale: float = spec(
        1.5,
        lo=0.1,
        doc="ASSUMED: noise std of the noisiest throw over the filter's stereo model "
        "(0.25 px against 0.17 px disparity noise)",
    )
    floor_std: float = spec(
        0.004, unit="m", lo=0.0, lo_open=True, doc="noise std added on every axis (model floor)"
    )


class FlightFit(NamedTuple):
    """A free-flight fit at the newest detection.

    Attributes:
        t: stamp of the newest detection [s].
        mean: [X Y Z Vx Vy Vz] in base at ``t`` [m, m/s], shape (6,).
        cov: its covariance, shape (6, 6).
        chi2: residual chi-square of the fit.
        z: the newest detection [m], shape (3,).
        n: detections the fit used.
        uses_newest: the newest detection is one of them (not dropped as an outlier).
    """

    t: float
    mean: np.ndarray
    cov: np.ndarray
    chi2: float
    z: np.ndarray
    n: int
    uses_newest: bool = True


HOLD_POINTS = 10  # detections kept before the window to locate the hold


def _stamp(point: tuple) -> float:
    return point[0]


def fit_free_flight(
    times: np.ndarray,
    points: np.ndarray,
    covs: np.ndarray,
    gravity: float,
    masks: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least-squares free flights through subsets of ``points`` [m] (N, 3) seen at
    ``times`` [s] (N,) with noise covariances ``covs`` [m^2] (N, 3, 3).

    Each row of ``masks`` (S, N) bool selects the points of one fit (default: one fit, all
    points). Every state is at the last time ``times[-1]``, whether or not that point is used.

    Returns:
        (means (S, 6), covariances (S, 6, 6), residual chi-squares (S,)).
    """
    if masks is None:
        masks = np.ones((1, len(times)), dtype=bool)
    m = masks.astype(float)
    dt = times - times[-1]
    w = np.linalg.inv(covs)  # (N, 3, 3)
    y = np.array(points, dtype=float)
    y[:, 2] += 0.5 * gravity * dt * dt  # remove the known gravity term
    # per point: A_i = [I, dt_i I]; info_i = A_i^T W_i A_i, rhs_i = A_i^T W_i y_i
    info_i = np.empty((len(dt), 6, 6))
    info_i[:, :3, :3] = w
    info_i[:, :3, 3:] = info_i[:, 3:, :3] = dt[:, None, None] * w
    info_i[:, 3:, 3:] = (dt * dt)[:, None, None] * w
    wy = np.einsum("nij,nj->ni", w, y)
    rhs_i = np.concatenate([wy, dt[:, None] * wy], axis=1)
    info = np.einsum("sn,nij->sij", m, info_i)
    cov = np.linalg.inv(info)
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    x = np.einsum("sij,sj->si", cov, m @ rhs_i)
    res = y[None] - (x[:, None, :3] + dt[None, :, None] * x[:, None, 3:])  # (S, N, 3)
    c2 = np.einsum("sn,sni,nij,snj->s", m, res, w, res)
    return x, cov, c2


@functools.lru_cache(maxsize=32)
def _subsets(n: int, max_drop: int) -> tuple[np.ndarray, np.ndarray]:
    """Masks (S, n) keeping all but up to ``max_drop`` points (at least 4 kept), and the number
    each drops (S,); the full set first."""
    rows = []
    for drop in range(min(max_drop, n - 4) + 1):
        for out in itertools.combinations(range(n), drop):
            keep = np.ones(n, dtype=bool)
            keep[list(out)] = False
            rows.append(keep)
    masks = np.array(rows)
    masks.setflags(write=False)
    dropped = n - masks.sum(axis=1)
    dropped.setflags(write=False)
    return masks, dropped


class LaunchDetector:
    """Feeds on accepted detections; :meth:`add` returns the fit when a launch is declared.

    Args:
        cfg: launch parameters.
        fcfg: filter parameters (stereo noise model, gravity).
        sensor: camera origin in base [m], shape (3,).
        cameras: how many cameras feed it: the detections kept before the window to locate
            the hold are ``HOLD_POINTS`` per camera (the same time span as one camera's).
        window: detections per fit (default ``cfg.window``; several cameras: ``[fusion]
            launch_window``).
    """

    def __init__(
        self, cfg: LaunchConfig, fcfg: FilterConfig, sensor, cameras: int = 1, window=None
    ):
        self.cfg, self.fcfg = cfg, fcfg
        self.window = cfg.window if window is None else int(window)
        self.sensor = np.asarray(sensor, dtype=float)
        # the window, and before it the detections that show where the ball was held
        # (stamp, position, noise covariance, camera id) of each detection
        self.points: deque[tuple[float, np.ndarray, np.ndarray, str | None]] = deque(
            maxlen=self.window + HOLD_POINTS * max(1, cameras)
        )
        self.passed = 0
        self.fits = 0
        self.launches = 0

    def reset(self) -> None:
        """Forget everything (a new ball)."""
        self.points.clear()
        self.passed = 0

    def add(
        self,
        t: float,
        z: np.ndarray,
        sensor=None,
        fcfg: FilterConfig | None = None,
        camera: str | None = None,
    ) -> FlightFit | None:
        """A detection stamped ``t`` [s] at ``z`` [m] (base); the fit if this declares a launch.

        ``sensor`` (origin [m] (3,)) and ``fcfg`` (its stereo noise model) name the camera that
        took it (None: the detector's own). With ``sensor`` given (several cameras), a detection
        older than the newest one is put in its place in time (another camera's newer one came
        first) and the window is fitted again; without, it is ignored (the filter rejected it).
        ``camera`` (its id; None: the default camera) is kept with it for the early belief
        (:func:`thinkfast.estimate.early_belief.flight_run`); the fit does not read it.
        """
        if not self.insert(t, z, sensor, fcfg, camera):
            return None
        fit = self.fit()
        if fit is None or not self.passes(fit):
            self.passed = 0
            return None
        self.passed += 1
        if self.passed < self.cfg.confirm:
            return None
        self.launches += 1
        return fit

    def insert(
        self,
        t: float,
        z: np.ndarray,
        sensor=None,
        fcfg: FilterConfig | None = None,
        camera: str | None = None,
    ) -> bool:
        """Keep the detection (arguments as :meth:`add`) in stamp order; False when it is
        ignored (late or duplicated)."""
        z = np.asarray(z, dtype=float)
        point = (float(t), z, self._cov(z, sensor, fcfg), camera)
        if self.points and t <= self.points[-1][0]:
            if sensor is None or t < self.points[0][0] or any(p[0] == t for p in self.points):
                return False  # late or duplicated: the filter has rejected it too
            pts = sorted([*self.points, point], key=_stamp)
            self.points = deque(pts, maxlen=self.points.maxlen)
        else:
            self.points.append(point)
        return True

    def fit(self) -> FlightFit | None:
        """The free-flight fit of the newest detections (up to ``window`` of them, within
        ``max_span``); None with fewer than 4."""
        if not self.points:
            return None
        fit = self._robust_fit(self._window(list(self.points), self.points[-1][0]))
        self.fits += fit is not None
        return fit

    def _window(self, points: list, t_new: float) -> list:
        """The newest of ``points`` (up to ``window``) no older than ``max_span`` before
        ``t_new``."""
        return [p for p in points if t_new - p[0] <= self.cfg.max_span][-self.window :]

    def _cov(self, z: np.ndarray, sensor=None, fcfg: FilterConfig | None = None) -> np.ndarray:
        """Noise covariance of a detection at ``z`` [m^2] (3, 3) seen from ``sensor`` with the
        model of ``fcfg`` (None: the detector's own): scaled stereo model + floor."""
        cfg = self.cfg
        where = self.sensor if sensor is None else np.asarray(sensor, dtype=float)
        r = stereo_r(z, where, self.fcfg if fcfg is None else fcfg)
        return cfg.noise_scale * cfg.noise_scale * r + cfg.floor_std * cfg.floor_std * np.eye(3)

    def _robust_fit(self, window: list) -> FlightFit | None:
        """The fit at ``times[-1]`` over the subset (dropping up to ``max_drop`` points) with the
        lowest residual chi-square plus the 3-dof ``1 - alpha`` quantile per dropped point: a
        point is called a gross outlier only when leaving it out explains the rest better by
        that much. None with fewer than 4 detections."""
        if len(window) < 4:
            return None
        times = np.array([p[0] for p in window])
        pts = np.array([p[1] for p in window])
        covs = np.array([p[2] for p in window])
        cfg = self.cfg
        masks, dropped = _subsets(len(pts), cfg.max_drop)
        x, cov, c2 = fit_free_flight(times, pts, covs, self.fcfg.gravity, masks)
        k = int(np.argmin(c2 + chi2_limit(cfg.alpha, 3) * dropped))
        n = int(len(pts) - dropped[k])
        newest = bool(masks[k, -1])
        return FlightFit(float(times[-1]), x[k], cov[k], float(c2[k]), pts[-1].copy(), n, newest)

    def _left_hold(self, fit: FlightFit) -> bool:
        """The newest detection is nearer the plane than where the ball was held, by more than
        ``sigmas`` of its depth noise (where the hold was seen: the median of the detections
        before the window, at least ``HOLD_POINTS // 2`` of them)."""
        before = [p[1] for p in self.points if fit.t - p[0] > self.cfg.max_span]
        if len(before) < HOLD_POINTS // 2:
            return True  # first seen in flight: nothing to compare with
        hold = np.median(np.array(before), axis=0)
        sd_x = math.sqrt(self.points[-1][2][0, 0])
        return bool(hold[0] - fit.z[0] > self.cfg.sigmas * sd_x)

    def consistent(self, fit: FlightFit) -> bool:
        """The fit explains its points: residual chi-square within its ``1 - alpha`` quantile
        (``3 n - 6`` degrees of freedom)."""
        return fit.chi2 <= chi2_limit(self.cfg.alpha, 3 * fit.n - 6)

    def _approaching(self, fit: FlightFit) -> bool:
        speed_lo = -fit.mean[3] - self.cfg.sigmas * float(np.sqrt(fit.cov[3, 3]))
        return speed_lo > self.cfg.min_speed

    def passes(self, fit: FlightFit) -> bool:
        """Residual and approach-speed tests, on the fit and (``check_without_newest``) on the
        window without its newest point (see the module doc)."""
        if not (fit.uses_newest and self.consistent(fit) and self._approaching(fit)):
            return False
        if self.cfg.check_hold and not self._left_hold(fit):
            return False
        if not self.cfg.check_without_newest:
            return True
        rest = list(self.points)[:-1]
        older = self._window(rest, fit.t)
        if self._flight(older):
            return True
        # too few to leave a gross outlier out (the fit keeps four): a dropout in the span
        # would hold a real flight back until the outlier has left; the window the detector
        # had before the newest point came (within max_span of the one before it) decides
        return len(older) <= 4 and self._flight(self._window(rest, rest[-1][0]) if rest else [])

    def _flight(self, window: list) -> bool:
        """The robust fit of ``window`` is consistent and approaches the plane."""
        older = self._robust_fit(window)
        return older is not None and self.consistent(older) and self._approaching(older)
