"""Synthetic ZED 2i frames: the left image and the XYZ image of a ball, as the bridge sends them.

A pinhole camera (:class:`~thinkfast.sim.camera.CameraModelConfig`: focal length, image size,
baseline, exposure, pixel noise) looks along +x of the ``camera`` frame (REP-103) at a static
scene: a back wall, the floor, and clutter whose colours stay out of the ball's band. Made once
per renderer: the background image (with texture), its XYZ image (with per-pixel depth noise and
holes). Per frame only the ball's window is drawn:

* image: the ball's disc at every sub-sample of the exposure (motion blur), anti-aliased, shaded
  darker towards its rim, blended over the background, plus sensor noise (whole frame: a random
  window of a noise field made once);
* XYZ: ray-sphere intersections of the cloud pixels the ball covers for most of the exposure;
  depth noise along the ray with the camera model's std ``d^2 sigma_disp / (f B)``, split into a
  part common to the ball (stereo matching is correlated over the ball) and a per-pixel part
  (each pixel's XYZ lies on its own viewing ray, as a stereo camera's does); holes at random
  pixels and at the blurred edges. The camera model's lateral noise (``pixel_sigma``) is not
  added: in frames it is the detector's own image error, which the model's covariance bounds.

Randomness comes from the ``rng`` arguments (and the seed of the scene); no clocks, no I/O.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import cv2
import numpy as np

from thinkfast.config import spec
from thinkfast.perception.frame import frame_buffer
from thinkfast.sim.camera import CameraModelConfig, noise_covariance


@dataclasses.dataclass(frozen=True)
class FrameRenderConfig:
    """Scene, ball appearance and XYZ encoding of the synthetic camera (ASSUMPTIONS)."""

    ball_radius: float = spec(0.0335, doc="ball radius (67 mm tennis ball)", unit="m", lo=0.0)
    ball_bgr: tuple[int, int, int] = spec(
        (60, 235, 205), doc="lit ball colour, BGR (optic yellow: HSV about 35, 190, 235)",
        length=3, lo=0, hi=255,
    )  # fmt: skip
    rim_shade: float = spec(0.55, doc="brightness at the ball's silhouette (1 at its centre)")
    image_noise: float = spec(2.0, doc="sensor noise std per pixel", unit="DN", lo=0.0)
    max_blur_samples: int = spec(12, doc="exposure sub-samples for motion blur", lo=1)
    depth_correlation: float = spec(
        0.5, doc="share of the depth noise variance common to the ball's pixels", lo=0.0, hi=1.0
    )
    invalid_fraction: float = spec(0.05, doc="ball pixels without depth", lo=0.0, hi=1.0)
    edge_invalid: float = spec(0.5, doc="blurred-edge pixels without depth", lo=0.0, hi=1.0)
    wall_distance: float = spec(12.0, doc="back wall depth", unit="m", lo=0.5)
    floor_below: float = spec(0.30, doc="floor below the lens (camera height)", unit="m", lo=0.0)
    background_disparity: float = spec(0.2, doc="disparity noise of the scene", unit="px", lo=0.0)
    background_invalid: float = spec(0.05, doc="scene pixels without depth", lo=0.0, hi=1.0)
    clutter: int = spec(80, doc="clutter shapes in the scene", lo=0)
    avoid_hsv: tuple[tuple[int, int, int], tuple[int, int, int]] = spec(
        ((19, 60, 40), (51, 255, 255)), doc="HSV band no scene pixel may fall in (ball colours)"
    )
    xyz_dtype: str = spec("float32", doc="XYZ image dtype", choices=("float32", "float16"))
    xyz_step: int = spec(1, doc="XYZ image at 1/n of the image resolution", lo=1, hi=8)


class Truth(NamedTuple):
    """What was rendered: ball centre in ``camera`` at mid exposure [m] (3,) or None (no ball
    in view), the inlier noise model's covariance [m^2] (3, 3) there, motion blur [px]."""

    position: np.ndarray | None
    covariance: np.ndarray | None
    blur_px: float


def _safe_colours(rng: np.random.Generator, n: int, avoid) -> np.ndarray:
    """``n`` BGR colours outside the HSV band ``avoid``, some of them close to it on purpose."""
    (h0, s0, _), (h1, _, _) = avoid
    hue = np.concatenate([rng.uniform(0, h0 - 6, n), rng.uniform(h1 + 6, 180, n)])
    hue = rng.choice(hue, n)
    sat = rng.uniform(0, 255, n)
    sat = np.where(rng.random(n) < 0.3, rng.uniform(0, s0 - 20, n), sat)
    hsv = np.stack([hue, sat, rng.uniform(40, 250, n)], 1).astype(np.uint8)[None]
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0]


def background_image(size, cfg: FrameRenderConfig, seed: int) -> np.ndarray:
    """Scene image (H, W, 3) uint8: wall, floor, textured clutter, nothing in ``avoid_hsv``."""
    w, h = size
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[: h // 2] = (150, 140, 135)  # wall
    img[h // 2 :] = (70, 90, 110)  # floor
    cols = _safe_colours(rng, cfg.clutter, cfg.avoid_hsv)
    for c in cols:
        c = tuple(int(v) for v in c)
        x, y = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        a, b = int(rng.uniform(5, 160)), int(rng.uniform(5, 120))
        if rng.random() < 0.5:
            cv2.rectangle(img, (x - a, y - b), (x + a, y + b), c, -1, cv2.LINE_8)
        else:
            cv2.ellipse(img, (x, y), (a, b), rng.uniform(0, 180), 0, 360, c, -1, cv2.LINE_8)
    tex = cv2.GaussianBlur(rng.normal(0, 12, (h, w, 1)).astype(np.float32), (0, 0), 2.0)[..., None]
    img = np.clip(img + tex + rng.normal(0, 2, (h, w, 3)), 0, 255).astype(np.uint8)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    bad = cv2.inRange(
        hsv, np.array(cfg.avoid_hsv[0], np.uint8), np.array(cfg.avoid_hsv[1], np.uint8)
    )
    img[bad > 0] = (128, 128, 128)
    img.setflags(write=False)
    return img


class FrameRenderer:
    """Renders frame payloads (docs/CAMERA_FRAMES.md) of one static scene.

    Args:
        cfg: scene and ball.
        camera: intrinsics (principal point at the image centre), baseline, exposure, pixel noise.
        seed: scene seed (clutter, texture, scene depth noise and holes).
    """

    def __init__(self, cfg: FrameRenderConfig, camera: CameraModelConfig, seed: int = 0):
        self.cfg, self.camera = cfg, camera
        self.size = (w, h) = camera.image_size
        f = camera.focal_px
        self.intrinsics = (f, f, (w - 1) / 2.0, (h - 1) / 2.0)
        s = cfg.xyz_step
        self.xyz_size = (w // s, h // s)
        self.xyz_roi = (0, 0, (w // s) * s, (h // s) * s)
        self.background = background_image(self.size, cfg, seed)
        rng = np.random.default_rng([seed, 1])
        self.background_xyz = self._scene_xyz(rng).astype(cfg.xyz_dtype)
        noise = rng.normal(0.0, cfg.image_noise, (h + 64, w + 64, 3))
        self._noise_pos = np.clip(noise, 0, 255).astype(np.uint8)
        self._noise_neg = np.clip(-noise, 0, 255).astype(np.uint8)

    def _rays(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Rays (R, C, 3) with unit x of the image points (u = cols, v = rows) [px]."""
        f, _, cx, cy = self.intrinsics
        uu, vv = np.meshgrid(cols, rows)
        return np.stack([np.ones_like(uu), (cx - uu) / f, (cy - vv) / f], axis=-1)

    def _cells(self, x0: int, x1: int, y0: int, y1: int):
        """XYZ cell index ranges covering image columns x0..x1, rows y0..y1, and their rays."""
        s = self.cfg.xyz_step
        j0, j1 = x0 // s, min(self.xyz_size[0], -(-x1 // s))
        i0, i1 = y0 // s, min(self.xyz_size[1], -(-y1 // s))
        off = (s - 1) / 2.0
        rays = self._rays(np.arange(j0, j1) * s + off, np.arange(i0, i1) * s + off)
        return (i0, i1, j0, j1), rays

    def _scene_xyz(self, rng: np.random.Generator) -> np.ndarray:
        cfg = self.cfg
        (_, _, _, _), rays = self._cells(0, self.xyz_roi[2], 0, self.xyz_roi[3])
        with np.errstate(divide="ignore"):
            t_floor = np.where(rays[..., 2] < 0, -cfg.floor_below / rays[..., 2], np.inf)
        t = np.minimum(t_floor, cfg.wall_distance)
        sd = t**2 * cfg.background_disparity / (self.camera.focal_px * self.camera.baseline)
        t = t + sd * rng.standard_normal(t.shape)
        xyz = rays * t[..., None]
        xyz[rng.random(t.shape) < cfg.background_invalid] = np.nan
        return xyz.astype(np.float32)

    def render(
        self,
        stamp: float,
        seq: int | None,
        p_cam: np.ndarray | None,
        v_cam: np.ndarray | None,
        disparity_sigma: float,
        rng: np.random.Generator,
    ) -> tuple[bytearray, Truth]:
        """One frame payload and what it shows.

        Args:
            stamp: capture time (mid exposure) [s].
            seq: frame counter, or None.
            p_cam: true ball centre in ``camera`` at mid exposure [m] (3,), or None: no ball.
            v_cam: its velocity in ``camera`` [m/s] (3,) (motion blur), or None: still.
            disparity_sigma: disparity noise std of this throw [px].
            rng: noise source.
        """
        cfg = self.cfg
        fb = frame_buffer(
            stamp, self.intrinsics, self.size, seq, "bgr8", cfg.xyz_dtype, 3, self.xyz_size,
            self.xyz_roi,
        )  # fmt: skip
        w, h = self.size
        ox, oy = (int(v) for v in rng.integers(0, 64, 2))
        img = cv2.add(self.background, self._noise_pos[oy : oy + h, ox : ox + w])
        cv2.subtract(img, self._noise_neg[oy + 1 : oy + 1 + h, ox : ox + w], dst=fb.image)
        fb.xyz[...] = self.background_xyz
        if p_cam is None:
            return fb.payload, Truth(None, None, 0.0)
        p = np.asarray(p_cam, float)
        v = np.zeros(3) if v_cam is None else np.asarray(v_cam, float)
        blur = self._draw(fb, p, v, disparity_sigma, rng)
        if blur is None:
            return fb.payload, Truth(None, None, 0.0)
        cov = noise_covariance(p[None], disparity_sigma, self.camera)[0]
        return fb.payload, Truth(p.copy(), cov, blur)

    def _draw(self, fb, p, v, sigma_disp, rng) -> float | None:
        """Draw the ball into ``fb``; its motion blur [px], or None if it is not in the image."""
        cfg, cam = self.cfg, self.camera
        f, _, cx, cy = self.intrinsics
        r = cfg.ball_radius
        if p[0] < cam.min_range or np.linalg.norm(p) > cam.max_range:
            return None
        ends = p + np.outer([-0.5, 0.5], v) * cam.exposure
        uv = np.stack([cx - f * ends[:, 1] / ends[:, 0], cy - f * ends[:, 2] / ends[:, 0]], 1)
        blur = float(np.linalg.norm(uv[1] - uv[0]))
        k = min(cfg.max_blur_samples, 1 + math.ceil(blur / 1.5))
        sub = p + np.outer(np.linspace(-0.5, 0.5, k) if k > 1 else [0.0], v) * cam.exposure
        sub = sub[sub[:, 0] > r + 0.05]
        if len(sub) == 0:
            return None
        u = cx - f * sub[:, 1] / sub[:, 0]
        vv = cy - f * sub[:, 2] / sub[:, 0]
        rad = f * r / np.sqrt(np.maximum(sub[:, 0] ** 2 - r * r, 1e-9)) * 1.1 + 2.0
        w, h = self.size
        x0, x1 = max(0, int(np.floor((u - rad).min()))), min(w, int(np.ceil((u + rad).max())) + 1)
        y0, y1 = max(0, int(np.floor((vv - rad).min()))), min(h, int(np.ceil((vv + rad).max())) + 1)
        if x1 <= x0 or y1 <= y0:
            return None
        self._draw_image(fb.image, sub, (x0, x1, y0, y1), rng)
        self._draw_xyz(fb.xyz, sub, (x0, x1, y0, y1), sigma_disp, rng)
        return blur

    def _draw_image(self, image, sub, box, rng) -> None:
        cfg, f = self.cfg, self.intrinsics[0]
        x0, x1, y0, y1 = box
        rays = self._rays(np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float))
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        cover = np.zeros(rays.shape[:2])
        lit = np.zeros(rays.shape[:2])
        for c in sub:
            dist = float(np.linalg.norm(c))
            ang = np.arccos(np.clip(rays @ (c / dist), -1.0, 1.0))
            ang_r = math.asin(min(1.0, cfg.ball_radius / dist))
            part = np.clip(0.5 - (ang - ang_r) * f, 0.0, 1.0)  # anti-aliased edge, ~1 px wide
            rho = np.clip(ang / ang_r, 0.0, 1.0)
            cover += part
            lit += part * (cfg.rim_shade + (1.0 - cfg.rim_shade) * np.sqrt(1.0 - rho**2))
        n = len(sub)
        shade = lit / np.maximum(cover, 1e-9)
        cover /= n
        patch = image[y0:y1, x0:x1].astype(np.float64)
        ball = np.asarray(cfg.ball_bgr, float) * shade[..., None]
        out = patch * (1.0 - cover[..., None]) + ball * cover[..., None]
        noise = rng.normal(0.0, cfg.image_noise, out.shape) * (cover[..., None] > 0)
        image[y0:y1, x0:x1] = np.clip(out + noise, 0, 255).astype(np.uint8)

    def _draw_xyz(self, xyz, sub, box, sigma_disp, rng) -> None:
        cfg, cam = self.cfg, self.camera
        (i0, i1, j0, j1), rays = self._cells(*box)
        if i1 <= i0 or j1 <= j0:
            return
        r2 = cfg.ball_radius**2
        dd = (rays**2).sum(-1)
        hits = np.zeros(rays.shape[:2])
        t_sum = np.zeros(rays.shape[:2])
        for c in sub:
            b = rays @ c
            disc = b * b - dd * (c @ c - r2)
            hit = disc >= 0.0
            t = (b - np.sqrt(np.where(hit, disc, 0.0))) / dd  # depth x of the front surface
            hits += hit
            t_sum += np.where(hit, t, 0.0)
        frac = hits / len(sub)
        ball = frac >= 0.5
        edge = (frac > 0.0) & ~ball
        t = t_sum / np.maximum(hits, 1)
        sd = t**2 * sigma_disp / (cam.focal_px * cam.baseline)
        rho = cfg.depth_correlation
        e = math.sqrt(rho) * rng.standard_normal() + math.sqrt(1 - rho) * rng.standard_normal(
            t.shape
        )
        pts = rays * (t + sd * e)[..., None]
        pts[ball & (rng.random(t.shape) < cfg.invalid_fraction)] = np.nan
        block = xyz[i0:i1, j0:j1]
        block[ball] = pts[ball].astype(block.dtype)
        block[edge & (rng.random(t.shape) < cfg.edge_invalid)] = np.nan
