"""The ball filter's types and noise model: its configuration, the belief it carries, what an
update did, and the range-dependent stereo measurement noise (docs/FACTS.md).

The filter's steps (:mod:`thinkfast.estimate.filter`) are functions over these; that module
re-exports every name here, so callers import from either.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from statistics import NormalDist
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec

STATUS_FIRST = "first"
STATUS_INIT = "init"
STATUS_UPDATED = "updated"
STATUS_LATE = "late"
STATUS_PAST = "past"


@dataclasses.dataclass(frozen=True)
class FilterConfig:
    """Ball filter parameters (TOML table, loaded with :func:`thinkfast.config.from_dict`).

    The noise defaults are assumptions (a ZED 2i at a few metres, a tennis ball) until tuned on
    logged throws.
    """

    accel_psd: tuple[float, ...] = spec(
        (4.0, 4.0, 4.0),
        doc="white-acceleration spectral density q (x, y, z): process noise Q",
        unit="m^2/s^3",
        lo=0.0,
        length=3,
    )
    r0_std: tuple[float, ...] = spec(
        (0.03, 0.02, 0.02),
        doc="initial measurement noise standard deviation (x, y, z): R0",
        unit="m",
        lo=0.0,
        lo_open=True,
        length=3,
    )
    p0_std: tuple[float, ...] = spec(
        (0.0, 0.0, 0.0, 0.5, 0.5, 0.5),
        doc="standard deviation added in quadrature to the two-point initial covariance: P0",
        unit="m, m/s",
        lo=0.0,
        length=6,
    )
    alpha: float = spec(
        0.99, doc="confidence of the per-axis chi-square(1) innovation test", lo=0.5, hi=0.999999
    )
    shrink_scale: float = spec(
        2.0,
        doc="exponential decay of an outlier beyond the threshold",
        unit="sigma",
        lo=0.0,
        lo_open=True,
    )
    window: int = spec(20, doc="revised innovations in the sliding window", lo=2)
    warmup: int = spec(
        10, doc="weight of R0 in the R estimate, in innovations (soft warm-up)", lo=0
    )
    gross_sigma: float = spec(
        8.0,
        doc="innovations beyond this enter the window exponentially shrunk",
        unit="sigma",
        lo=0.0,
        lo_open=True,
    )
    r_min_std: float = spec(
        0.002, doc="floor on each adapted measurement noise std", unit="m", lo=0.0, lo_open=True
    )
    reset_after: int = spec(
        3, doc="consecutive revised innovations on an axis before it is re-initialised", lo=1
    )
    drag: float = spec(
        0.0,
        doc="quadratic drag coefficient k, a = -k |v| v (0: the paper's model)",
        unit="1/m",
        lo=0.0,
    )
    gravity: float = spec(9.81, doc="gravity, acting along -z of base", unit="m/s^2", lo=0.0)
    adaptive: bool = spec(True, doc="adapt R from the innovation window (eq. 4-5)")
    robust: bool = spec(True, doc="per-axis gate with exponential shrink (eq. 3) and recovery")
    reset_all_axes: bool = spec(
        False, doc="when one axis restarts (a manoeuvre, e.g. a release), restart all three"
    )
    stereo_depth: float = spec(
        0.0,
        unit="1/m",
        lo=0.0,
        doc="stereo depth noise sigma = stereo_depth * range^2 along the viewing ray (0: off); "
        "ZED 2i HD720, 0.17 px disparity: 0.17 / (532 px * 0.12 m) = 0.0027",
    )
    stereo_lateral: float = spec(
        0.0,
        unit="1",
        lo=0.0,
        doc="stereo lateral noise sigma = stereo_lateral * range (0: off); 0.5 px / 532 px",
    )


class Belief(NamedTuple):
    """Filter state; immutable by convention (step functions return new arrays).

    Attributes:
        t: time of the belief [s].
        mean: state mean [X Y Z Vx Vy Vz] in base [m, m/s], shape (6,).
        cov: state covariance, shape (6, 6).
        r: current measurement noise covariance [m^2], shape (3, 3) (diagonal once adapted).
        window: ring buffer of revised innovations [m], shape (window, 3).
        n_innov: revised innovations pushed so far (the window holds ``min(n, window)``).
        t_meas: stamp of the last accepted measurement [s].
        z_meas: that measurement [m], shape (3,).
        gated: per axis, consecutive updates whose innovation was revised, shape (3,).
        n_meas: accepted measurements (0: empty, 1: waiting for the second one).
        n_late: measurements rejected as late, duplicated or out of order.
        n_outliers: axis-measurements revised by the robust gate.
        n_resets: axis re-initialisations by the recovery step.
        window_model: the measurement-noise model at each innovation of ``window`` [m^2],
            shape (window, 3).
        s_meas: origin of the sensor that took ``z_meas`` [m] (3,), or None (no sensor given).
    """

    t: float
    mean: np.ndarray
    cov: np.ndarray
    r: np.ndarray
    window: np.ndarray
    n_innov: int
    t_meas: float
    z_meas: np.ndarray
    gated: np.ndarray
    n_meas: int
    n_late: int
    n_outliers: int
    n_resets: int
    window_model: np.ndarray
    s_meas: np.ndarray | None = None


class UpdateInfo(NamedTuple):
    """What one :func:`update` did.

    Attributes:
        status: ``"first"``, ``"init"``, ``"updated"``, ``"past"`` (out of sequence) or
            ``"late"``.
        innovation: raw innovation z - x_pred [m], shape (3,) (zeros unless updated).
        weight: per-axis factor applied to the innovation (1 = inlier), shape (3,).
        nis: normalised innovation squared v^T S^-1 v of the raw innovation.
        reset: axes re-initialised by the recovery step, shape (3,) bool.
    """

    status: str
    innovation: np.ndarray
    weight: np.ndarray
    nis: float
    reset: np.ndarray


_ZERO3 = np.zeros(3)
_ZERO33 = np.zeros((3, 3))
_ONE3 = np.ones(3)
_NO3 = np.zeros(3, dtype=bool)
for _a in (_ZERO3, _ZERO33, _ONE3, _NO3):
    _a.setflags(write=False)


def empty(cfg: FilterConfig) -> Belief:
    """A belief with no measurement yet (time -inf)."""
    return Belief(
        t=-math.inf,
        mean=np.zeros(6),
        cov=np.eye(6),
        r=np.diag(np.square(cfg.r0_std)),
        window=np.zeros((cfg.window, 3)),
        n_innov=0,
        t_meas=-math.inf,
        z_meas=np.zeros(3),
        gated=np.zeros(3, dtype=np.intp),
        n_meas=0,
        n_late=0,
        n_outliers=0,
        n_resets=0,
        window_model=np.zeros((cfg.window, 3)),
    )


@functools.lru_cache(maxsize=16)
def gate_threshold(alpha: float) -> float:
    """Per-axis gate c = sqrt(chi2_1^-1(alpha)) [sigma], the two-sided normal quantile."""
    return NormalDist().inv_cdf(0.5 + 0.5 * alpha)


@functools.lru_cache(maxsize=16)
def clip_consistency(alpha: float) -> float:
    """E[min(x^2, c^2)] for x ~ N(0, 1): how much clipping at the gate shrinks a variance."""
    c = gate_threshold(alpha)
    tail = 1.0 - NormalDist().cdf(c)
    return (
        1.0
        - 2.0 * tail
        - 2.0 * c * math.exp(-0.5 * c * c) / math.sqrt(2.0 * math.pi)
        + (2.0 * c * c * tail)
    )


def stereo_r(z: np.ndarray, sensor: np.ndarray | None, cfg: FilterConfig) -> np.ndarray:
    """Range-dependent stereo noise [m^2] (3, 3) of a measurement ``z`` seen from ``sensor``.

    Depth noise grows with range squared along the viewing ray, lateral noise with range
    (docs/FACTS.md): ``R = s_l^2 I + (s_d^2 - s_l^2) u u^T``. Zero when the model is off or no
    sensor position is given.
    """
    if sensor is None or (cfg.stereo_depth == 0.0 and cfg.stereo_lateral == 0.0):
        return _ZERO33
    d = np.asarray(z, dtype=float) - sensor
    rng = float(np.sqrt(d @ d))
    if rng < 1e-6:
        return _ZERO33
    u = d / rng
    s_d, s_l = cfg.stereo_depth * rng * rng, cfg.stereo_lateral * rng
    return s_l * s_l * np.eye(3) + (s_d * s_d - s_l * s_l) * np.outer(u, u)
