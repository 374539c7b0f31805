"""The detector against rendered frames: detection rate, 3-D error against the noise model, false
detections on frames without a ball (bench/detect.py and the tests).

Balls are drawn uniformly in depth, anywhere in the image (kept a radius plus 10 px inside its
edges, so that the motion-blurred ball is whole) above the floor of the scene,
with throw-like velocities (towards the camera at 8-16 m/s, up to 3 m/s across) for motion
blur, and a disparity noise level drawn like the camera model's (once per frame here).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from thinkfast.perception.config import DetectConfig
from thinkfast.perception.detect import Found, detect
from thinkfast.perception.frame import parse_frame
from thinkfast.sim.camera import CameraModelConfig
from thinkfast.sim.images import FrameRenderer

CHI2_3_3SIGMA = 14.156  # chi-square, 3 dof, at the two-sided 3-sigma probability 0.9973


class CheckResult(NamedTuple):
    """Per frame with a ball (N,): truth (N, 3), estimate (N, 3) (NaN if missed), model std per
    axis (N, 3), squared Mahalanobis distance (N,) (NaN if missed), miss reasons; ball-free
    frames and how many gave a detection; detector times per frame [s]."""

    truth: np.ndarray
    estimate: np.ndarray
    sigma: np.ndarray
    mahalanobis2: np.ndarray
    misses: dict
    empty_frames: int
    false_detections: int
    seconds: np.ndarray


def sample_balls(
    n: int, depth: tuple[float, float], cam: CameraModelConfig, rng, floor_below: float = 0.30
):
    """``n`` ball centres [m] (n, 3) in ``camera`` inside the image and above the floor
    (``floor_below`` under the lens), and velocities [m/s]."""
    f = cam.focal_px
    w, h = cam.image_size
    d = rng.uniform(*depth, n)
    margin = 0.0335 * f / d + 2.0 + 8.0  # the whole blurred ball in the image
    u = rng.uniform(margin, w - 1 - margin) - (w - 1) / 2.0
    v_floor = np.minimum(h - 1 - margin, (h - 1) / 2.0 + f * (floor_below - 0.0335) / d)
    v = rng.uniform(margin, v_floor) - (h - 1) / 2.0
    p = np.stack([d, -u * d / f, -v * d / f], axis=1)
    vel = np.stack([-rng.uniform(8, 16, n), rng.uniform(-3, 3, n), rng.uniform(-3, 3, n)], 1)
    return p, vel


def run_check(
    renderers: list[FrameRenderer],
    cfg: DetectConfig,
    n_ball: int,
    n_empty: int,
    seed: int = 0,
    depth: tuple[float, float] = (1.0, 9.0),
) -> CheckResult:
    """Render ``n_ball`` frames with a ball and ``n_empty`` without (scenes taken in turn), detect.

    Only the detector (parse + detect) is timed, not the renderer.
    """
    rng = np.random.default_rng(seed)
    cam = renderers[0].camera
    p, vel = sample_balls(n_ball, depth, cam, rng)
    est = np.full((n_ball, 3), np.nan)
    sig = np.empty((n_ball, 3))
    m2 = np.full(n_ball, np.nan)
    misses: dict[str, int] = {}
    secs = []
    for i in range(n_ball):
        sd = rng.uniform(*cam.disparity_sigma)
        payload, truth = renderers[i % len(renderers)].render(1e9 + i, i, p[i], vel[i], sd, rng)
        payload = bytes(payload)
        t0 = time.perf_counter()
        res = detect(parse_frame(payload), cfg)
        secs.append(time.perf_counter() - t0)
        sig[i] = np.sqrt(np.diag(truth.covariance))
        if isinstance(res, Found):
            est[i] = res.position
            err = res.position - truth.position
            m2[i] = err @ np.linalg.solve(truth.covariance, err)
        else:
            misses[res.reason] = misses.get(res.reason, 0) + 1
    false = 0
    for i in range(n_empty):
        payload, _ = renderers[i % len(renderers)].render(2e9 + i, i, None, None, 0.2, rng)
        payload = bytes(payload)
        t0 = time.perf_counter()
        res = detect(parse_frame(payload), cfg)
        secs.append(time.perf_counter() - t0)
        false += isinstance(res, Found)
    return CheckResult(p, est, sig, m2, misses, n_empty, false, np.array(secs))


def summary(r: CheckResult) -> dict:
    """Plain figures: detection rate, error statistics in model sigmas, false detections."""
    found = np.isfinite(r.mahalanobis2)
    z = np.abs(r.estimate[found] - r.truth[found]) / r.sigma[found]
    m2 = r.mahalanobis2[found]
    return {
        "ball_frames": int(len(found)),
        "detection_rate": round(float(found.mean()), 4),
        "misses": dict(r.misses),
        "within_3sigma": round(float((m2 <= CHI2_3_3SIGMA).mean()), 4) if len(m2) else None,
        "mahalanobis_p50": round(float(np.sqrt(np.median(m2))), 3) if len(m2) else None,
        "mahalanobis_p99": round(float(np.sqrt(np.percentile(m2, 99))), 3) if len(m2) else None,
        "mahalanobis_max": round(float(np.sqrt(m2.max())), 3) if len(m2) else None,
        "axis_error_p99_sigma": [round(float(x), 3) for x in np.percentile(z, 99, axis=0)]
        if len(z)
        else None,
        "empty_frames": r.empty_frames,
        "false_detections": r.false_detections,
    }
