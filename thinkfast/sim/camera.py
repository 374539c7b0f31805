"""ZED 2i model: what the camera bridge would publish for one throw, in the ``camera`` frame.

Pure: randomness comes from the ``rng`` argument, time from the arguments (no clocks, no I/O).
The camera frame is REP-103 (x forward along the optical axis, y left, z up); its pose in
``base`` is a :class:`~thinkfast.contract.detection.CameraExtrinsic`. Units: m, s.

Each true ball centre is an inlier (stereo depth error along the viewing ray, lateral pixel
error), an outlier, or not seen (outside the image or the range, a dropout burst, a miss). The
camera's video mode (:func:`mode_model`) sets the focal length, image size and frame rate.
Frames are captured every ``1 / rate`` from a random phase, stamped with the capture time plus
``stamp_bias`` and delivered ``latency`` later.

The noise model in full: docs/CAMERAS.md, "The ZED 2i model".
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.contract.camera_mode import DEFAULT_MODE, ZED_MODES, CameraSetup
from thinkfast.contract.detection import encode_detection
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.sim.throws import Throw, ball_states, observed_until


@dataclasses.dataclass(frozen=True)
class CameraModelConfig:
    """ZED 2i at HD720, 50 fps (docs/FACTS.md; :func:`mode_model` for another mode). Every
    noise figure is an ASSUMPTION until measured."""

    rate: float = spec(50.0, doc="frame rate (the paper's system)", unit="Hz", lo=0.0, lo_open=True)
    focal_px: float = spec(532.0, doc="focal length, HD720 rectified", unit="px", lo=0.0)
    baseline: float = spec(0.12, doc="stereo baseline", unit="m", lo=0.0, lo_open=True)
    image_size: tuple[int, int] = spec(
        (1280, 720), doc="image width, height (FOV 2 atan(n / 2f): 100 x 68 deg)", unit="px",
        length=2, lo=1,
    )  # fmt: skip
    disparity_sigma: tuple[float, float] = spec(
        (0.1, 0.25), doc="disparity noise std, drawn uniformly once per throw", unit="px",
        length=2, lo=0.0,
    )  # fmt: skip
    pixel_sigma: float = spec(0.5, doc="lateral (image) noise std", unit="px", lo=0.0)
    outlier_prob: float = spec(0.02, doc="gross outlier probability", lo=0.0, hi=1.0)
    outlier_error: tuple[float, float] = spec(
        (0.3, 1.5), doc="outlier depth error magnitude range", unit="m", length=2, lo=0.0
    )
    outlier_lateral: float = spec(
        0.2, doc="outlier lateral error std as a fraction of its depth error", lo=0.0
    )
    blur_outlier_prob: float = spec(
        0.1, doc="extra outlier probability at full motion blur", lo=0.0, hi=1.0
    )
    blur_full: float = spec(
        10.0, doc="motion blur (image travel per exposure) counted as full", unit="px", lo=1e-9
    )
    exposure: float = spec(0.005, doc="exposure time (sets motion blur)", unit="s", lo=0.0)
    dropout_rate: float = spec(
        0.05, doc="long-run fraction of frames without a detection", lo=0.0, hi=0.99
    )
    dropout_burst: float = spec(2.0, doc="mean length of a dropout burst", unit="frame", lo=1.0)
    latency: tuple[float, float] = spec(
        (0.030, 0.060), doc="capture-to-publish delay, uniform per frame", unit="s", length=2,
        lo=0.0,
    )  # fmt: skip
    reorder: bool = spec(False, doc="deliver in latency order (may reorder) instead of FIFO")
    stamp_bias: float = spec(0.0, doc="stamp minus true capture time (ZED host stamps)", unit="s")
    min_range: float = spec(0.3, doc="nearest depth measured", unit="m", lo=0.0)
    max_range: float = spec(20.0, doc="farthest distance measured", unit="m", lo=0.0)
    confidence: tuple[float, float] = spec(
        (0.6, 0.99), doc="detector confidence, uniform per detection", length=2, lo=0.0, hi=1.0
    )
    after_crossing: float = spec(
        0.1, doc="keep observing this long after the ball crosses the plane", unit="s", lo=0.0
    )
    detect_ranges: tuple[float, float, float, float] = spec(
        (6.0, 6.5, 7.5, 8.5), doc="depths of detect_probs", unit="m", length=4, lo=0.0
    )
    detect_probs: tuple[float, float, float, float] = spec(
        (1.0, 1.0, 1.0, 1.0),
        doc="chance the detector finds the ball at each of detect_ranges (linear between, "
        "constant beyond; independent per frame, ASSUMED); 1: always (HD720)",
        length=4, lo=0.0, hi=1.0,
    )  # fmt: skip


# The detector on rendered VGA frames with its VGA settings: 100 % to 6 m, 96 / 87 / 70 % at
# 6-7 / 7-8 / 8-9 m (docs/BENCHMARKS.md, "Perception front end"); at HD720 100 % to 9 m.
VGA_DETECT_PROBS = (1.0, 0.96, 0.87, 0.70)


def mode_model(cam: CameraSetup, base: CameraModelConfig | None = None) -> CameraModelConfig:
    """The camera model of ``cam``'s video mode and frame rate.

    Focal length, image size and frame rate come from the mode; the noise in pixels (disparity,
    lateral) stays ``base``'s, so in metres it scales as ``f_HD720 / f``. Motion blur is counted
    in the mode's pixels (``blur_full`` scaled by ``f / f_HD720``: the same blur relative to the
    ball's size gives the same outlier chance), and at VGA the detector misses far balls
    (:data:`VGA_DETECT_PROBS`). HD720 at ``base``'s rate is ``base`` itself.

    Args:
        cam: the camera's configured mode and frame rate (``[camera]``).
        base: the model at HD720 (default :class:`CameraModelConfig`).
    """
    base = CameraModelConfig() if base is None else base
    if cam.mode == DEFAULT_MODE and cam.fps == base.rate:
        return base
    mode = ZED_MODES[cam.mode]
    ratio = mode.focal_px / ZED_MODES[DEFAULT_MODE].focal_px
    return dataclasses.replace(
        base,
        rate=float(cam.fps),
        focal_px=mode.focal_px,
        image_size=mode.image_size,
        blur_full=base.blur_full * ratio,
        detect_probs=base.detect_probs if cam.mode == DEFAULT_MODE else VGA_DETECT_PROBS,
    )


class SimDetection(NamedTuple):
    """One simulated detection.

    Attributes:
        capture_stamp: stamp sent [s, wall clock]: capture time (+ ``stamp_bias``).
        delivery_time: when the bridge publishes it [s, wall clock].
        position_camera: measured ball centre in ``camera`` [m], shape (3,).
        seq: frame counter (gaps are frames without a detection).
        true_position_base: true ball centre in ``base`` at capture [m], shape (3,).
        is_outlier: a gross error was drawn.
        covariance: the inlier noise model's covariance in ``camera`` [m^2], shape (3, 3).
        confidence: detector confidence in [0, 1].
        camera: id of the camera (None: the default camera; the payload leaves ``camera`` out).
    """

    capture_stamp: float
    delivery_time: float
    position_camera: np.ndarray
    seq: int
    true_position_base: np.ndarray
    is_outlier: bool
    covariance: np.ndarray
    confidence: float
    camera: str | None = None


def depth_sigma(depth: np.ndarray, disparity_sigma: float, cfg: CameraModelConfig) -> np.ndarray:
    """Depth noise std ``d^2 sigma_disp / (f B)`` [m] at depths ``d`` [m] (N,)."""
    return np.asarray(depth) ** 2 * disparity_sigma / (cfg.focal_px * cfg.baseline)


def noise_covariance(
    p_cam: np.ndarray, disparity_sigma: float, cfg: CameraModelConfig
) -> np.ndarray:
    """Inlier measurement covariance [m^2] (N, 3, 3) at true positions ``p_cam`` [m] (N, 3)."""
    d = p_cam[:, 0]
    u = p_cam / d[:, None]
    s_z = depth_sigma(d, disparity_sigma, cfg)
    s_l = d * cfg.pixel_sigma / cfg.focal_px
    cov = s_z[:, None, None] ** 2 * u[:, :, None] * u[:, None, :]
    cov[:, 1, 1] += s_l**2
    cov[:, 2, 2] += s_l**2
    return cov


def measure(
    p_cam: np.ndarray, disparity_sigma: float, cfg: CameraModelConfig, rng: np.random.Generator
) -> np.ndarray:
    """Inlier measurements [m] (N, 3) of true positions ``p_cam`` [m] (N, 3) (depth > 0)."""
    d = p_cam[:, 0]
    e_d = rng.standard_normal(len(d)) * depth_sigma(d, disparity_sigma, cfg)
    lateral = rng.standard_normal((len(d), 2)) * (d * cfg.pixel_sigma / cfg.focal_px)[:, None]
    out = p_cam * ((d + e_d) / d)[:, None]
    out[:, 1:] += lateral
    return out


def gross_error(p_cam: np.ndarray, cfg: CameraModelConfig, rng: np.random.Generator) -> np.ndarray:
    """Outlier measurements [m] (N, 3): depth off by ``outlier_error`` either way, along the ray."""
    d = p_cam[:, 0]
    size = rng.uniform(*cfg.outlier_error, len(d))
    d_new = np.maximum(d + rng.choice([-1.0, 1.0], len(d)) * size, cfg.min_range)
    out = p_cam * (d_new / d)[:, None]
    out[:, 1:] += rng.standard_normal((len(d), 2)) * (cfg.outlier_lateral * size)[:, None]
    return out


def in_view(p_cam: np.ndarray, cfg: CameraModelConfig) -> np.ndarray:
    """Whether the camera can measure each ball centre ``p_cam`` [m] (N, 3): bool (N,)."""
    d = p_cam[:, 0]
    half_w, half_h = cfg.image_size[0] / 2.0, cfg.image_size[1] / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cfg.focal_px * p_cam[:, 1] / d
        w = cfg.focal_px * p_cam[:, 2] / d
    rng_ok = (d >= cfg.min_range) & (np.linalg.norm(p_cam, axis=1) <= cfg.max_range)
    return rng_ok & (np.abs(u) <= half_w) & (np.abs(w) <= half_h)


def blur_pixels(p_cam: np.ndarray, v_cam: np.ndarray, cfg: CameraModelConfig) -> np.ndarray:
    """Image travel of the ball during one exposure [px] (N,), from position and velocity (N, 3)."""
    d, vd = p_cam[:, 0], v_cam[:, 0]
    rate = cfg.focal_px * (v_cam[:, 1:] * d[:, None] - p_cam[:, 1:] * vd[:, None]) / d[:, None] ** 2
    return np.linalg.norm(rate, axis=1) * cfg.exposure


def outlier_probability(blur_px: np.ndarray, cfg: CameraModelConfig) -> np.ndarray:
    """Outlier probability (N,) given motion blur [px] (N,)."""
    return cfg.outlier_prob + cfg.blur_outlier_prob * np.minimum(blur_px / cfg.blur_full, 1.0)


def dropout_mask(n: int, cfg: CameraModelConfig, rng: np.random.Generator) -> np.ndarray:
    """Frames without a detection, bool (n,): a two-state Markov chain started in steady state.

    Leaving a burst has probability ``1 / dropout_burst``; entering one is set so that the
    long-run dropout fraction is ``dropout_rate``.
    """
    p_exit = 1.0 / cfg.dropout_burst
    p_enter = min(1.0, cfg.dropout_rate * p_exit / (1.0 - cfg.dropout_rate))
    u = rng.random(n)
    out = np.empty(n, dtype=bool)
    state = bool(rng.random() < cfg.dropout_rate)
    for i in range(n):
        state = (u[i] >= p_exit) if state else (u[i] < p_enter)
        out[i] = state
    return out


def observe(
    throw: Throw,
    cfg: CameraModelConfig,
    extrinsic: CameraExtrinsic,
    rng: np.random.Generator,
    t_release_wall: float = 0.0,
    until: float | None = None,
    seq0: int = 0,
    camera: str | None = None,
) -> list[SimDetection]:
    """Detections of one throw, from the ball's appearance in the hand to just past the plane.

    Args:
        throw: the throw (hold, then flight).
        cfg: camera model.
        extrinsic: camera pose in base.
        rng: the only source of randomness (noise level, phase, noise, outliers, dropouts).
        t_release_wall: wall-clock time of release [s]; stamps and delivery times use this clock.
        until: last capture time, after release [s]; None: ``cfg.after_crossing`` after the ball
            crosses ``throw.plane_x`` (a feint: the end of its rest).
        seq0: frame counter of the first frame (keep counting across throws).
        camera: the camera's id, stamped on every detection (None: the default camera).

    Returns:
        Detections in capture order (frames not seen are absent; their ``seq`` is skipped).
    """
    sigma_disp = rng.uniform(*cfg.disparity_sigma)
    period = 1.0 / cfg.rate
    if until is None:
        until = observed_until(throw, cfg.after_crossing)
    t = (
        -throw.t_release
        + rng.uniform(0.0, period)
        + period * np.arange(int(math.floor((until + throw.t_release) * cfg.rate)) + 1)
    )
    t = t[t <= until]
    n = len(t)
    p_base, v_base = ball_states(throw, t)
    R, c = extrinsic.rotation(), extrinsic.translation()
    p_cam, v_cam = (p_base - c) @ R, v_base @ R  # rows: R^T (p - c)
    seen = in_view(p_cam, cfg) & ~dropout_mask(n, cfg, rng)
    safe = np.where(seen[:, None], p_cam, 1.0)  # keep the kernels off frames not seen
    outlier = rng.random(n) < outlier_probability(blur_pixels(safe, v_cam, cfg), cfg)
    meas = np.where(
        outlier[:, None], gross_error(safe, cfg, rng), measure(safe, sigma_disp, cfg, rng)
    )
    cov = noise_covariance(safe, sigma_disp, cfg)
    latency = rng.uniform(*cfg.latency, n)
    conf = rng.uniform(*cfg.confidence, n)
    if min(cfg.detect_probs) < 1.0:  # drawn last: a model without misses keeps its draws
        found = np.interp(np.where(seen, p_cam[:, 0], 0.0), cfg.detect_ranges, cfg.detect_probs)
        seen &= rng.random(n) < found
    stamp = t_release_wall + t + cfg.stamp_bias
    capture = t_release_wall + t
    delivery = capture + latency
    out = []
    last = -math.inf
    for i in np.flatnonzero(seen):
        deliver = float(delivery[i]) if cfg.reorder else max(float(delivery[i]), last)
        last = deliver
        out.append(
            SimDetection(
                float(stamp[i]),
                deliver,
                meas[i].copy(),
                seq0 + int(i),
                p_base[i].copy(),
                bool(outlier[i]),
                cov[i].copy(),
                float(conf[i]),
                camera,
            )  # fmt: skip
        )
    return out


class SimCamera(NamedTuple):
    """One simulated camera: its id (None: the default camera), model and true pose in base
    (the run config holds the pose the daemon believes; a test may make them differ)."""

    id: str | None
    model: CameraModelConfig
    extrinsic: CameraExtrinsic


def observe_cameras(
    throw: Throw, cameras, seed: int, t_release_wall: float = 0.0
) -> list[SimDetection]:
    """Detections of one throw by every camera of ``cameras`` (a sequence of
    :class:`SimCamera`, the default camera first), merged in delivery order.

    Each camera draws from its own generator: the first from ``default_rng(seed)`` (so that
    the default camera alone gives exactly :func:`observe`'s detections, in its order), camera
    ``k`` from ``default_rng([seed, k])``: its own noise, frame phase, latency, dropouts and
    outliers, the same whichever other cameras run.
    """
    out = []
    for k, cam in enumerate(cameras):
        rng = np.random.default_rng(seed if k == 0 else [seed, k])
        out.append(observe(throw, cam.model, cam.extrinsic, rng, t_release_wall, camera=cam.id))
    if len(out) == 1:
        return out[0]
    return sorted((d for dets in out for d in dets), key=lambda d: d.delivery_time)


def detection_payload(sd: SimDetection, with_covariance: bool = False) -> bytes:
    """The zenoh payload of docs/INTERFACES.md ("Detections") for ``sd``, UTF-8 JSON.

    ``with_covariance`` adds the noise model's covariance (9 numbers, row major, camera frame).
    """
    cov = sd.covariance if with_covariance else None
    return encode_detection(
        sd.capture_stamp, sd.position_camera, "camera", sd.confidence, sd.seq, cov, sd.camera
    )
