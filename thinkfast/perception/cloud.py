"""Box -> 3-D ball centre: the paper's box shrink, then a robust centre of the XYZ pixels inside.

Pure (no I/O). Coordinates: left-image pixels, x right and y down, pixel ``k`` spanning
``[k, k + 1)`` (so a box ``x1`` is exclusive); XYZ points in the ``camera`` frame (x forward,
y left, z up) [m].
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.perception.config import CloudConfig, ShrinkConfig


class Centre(NamedTuple):
    """A ball centre from the point cloud.

    Attributes:
        position: ball centre in ``camera`` [m], shape (3,).
        n_valid: finite XYZ pixels in the box.
        n_inliers: of those, within the range gate around the median.
        spread: robust std of the inliers' range [m] (1.4826 MAD).
        confidence: in [0, 1], from ``n_inliers`` and ``spread``.
    """

    position: np.ndarray
    n_valid: int
    n_inliers: int
    spread: float
    confidence: float


def shrink_fraction(area_ratio: float, cfg: ShrinkConfig) -> float:
    """Fraction by which each side of a box shrinks, given box area / image area (> 0)."""
    x = (math.log10(max(area_ratio, 1e-12)) - math.log10(cfg.mid_area)) / cfg.width
    return cfg.far + (cfg.near - cfg.far) / (1.0 + math.exp(-max(-50.0, min(50.0, x))))


def shrink_box(
    box: tuple[float, float, float, float], image_size: tuple[int, int], cfg: ShrinkConfig
) -> tuple[float, float, float, float]:
    """``box`` = (x0, y0, x1, y1) [px] shrunk about its centre (each side at least 1 px)."""
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    s = 1.0 - shrink_fraction(w * h / float(image_size[0] * image_size[1]), cfg)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    hw, hh = 0.5 * max(w * s, 1.0), 0.5 * max(h * s, 1.0)
    return cx - hw, cy - hh, cx + hw, cy + hh


def box_points(
    xyz: np.ndarray,
    roi: tuple[int, int, int, int],
    box: tuple[float, float, float, float],
    scale: float = 1.0,
    mask: np.ndarray | None = None,
    mask_origin: tuple[int, int] = (0, 0),
) -> np.ndarray:
    """XYZ points [m] (N, 3) float32 of the cloud pixels that overlap ``box``.

    Args:
        xyz: point-cloud image (h, w, 3|4) covering the image rectangle ``roi`` = (x, y, w, h).
        roi: left-image rectangle of ``xyz`` [px].
        box: (x0, y0, x1, y1) in left-image pixels; at least the nearest cloud pixel is taken.
        scale: metres per cloud unit.
        mask: if given, keep only cloud pixels over a pixel set in this bool image (mh, mw)
            placed at left-image pixel ``mask_origin`` = (x, y) (for a cloud at a lower
            resolution: the first or last pixel of the cell, along each axis).
    """
    h, w = xyz.shape[:2]
    rx, ry, rw, rh = roi
    sx, sy = w / rw, h / rh

    def span(a: float, b: float, origin: int, k: float, n: int) -> tuple[int, int]:
        i0 = math.floor((a - origin) * k)
        i1 = max(math.ceil((b - origin) * k), i0 + 1)
        return max(0, i0), min(n, i1)

    j0, j1 = span(box[0], box[2], rx, sx, w)
    i0, i1 = span(box[1], box[3], ry, sy, h)
    if j1 <= j0 or i1 <= i0:
        return np.empty((0, 3), np.float32)
    pts = xyz[i0:i1, j0:j1, :3]
    if mask is not None:
        keep = np.zeros((i1 - i0, j1 - j0), bool)
        for rows in _cell_pixels(i0, i1, ry, sy, mask_origin[1], mask.shape[0]):
            for cols in _cell_pixels(j0, j1, rx, sx, mask_origin[0], mask.shape[1]):
                ri, ci = rows >= 0, cols >= 0
                keep[np.ix_(ri, ci)] |= mask[np.ix_(rows[ri], cols[ci])]
        pts = pts[keep]
    pts = pts.reshape(-1, 3).astype(np.float32)
    if scale != 1.0:
        pts *= np.float32(scale)
    return pts


def _cell_pixels(k0: int, k1: int, origin: int, scale: float, m0: int, n: int):
    """Mask indices (or -1 outside the mask) of the first and last image pixel of cloud cells
    k0..k1-1 along one axis (one pixel per cell when the cloud has the image's resolution)."""
    k = np.arange(k0, k1)
    first = np.floor(origin + k / scale + 1e-9).astype(int) - m0
    last = np.ceil(origin + (k + 1) / scale - 1e-9).astype(int) - 1 - m0
    out = []
    for idx in (first, last) if scale < 1.0 else (first,):
        out.append(np.where((idx >= 0) & (idx < n), idx, -1))
    return out


def centre_ray(u: float, v: float, intrinsics: tuple[float, float, float, float]) -> np.ndarray:
    """Unit viewing ray (3,) in ``camera`` of the image point (u, v) [px, pixel centres at
    integers] for intrinsics (fx, fy, cx, cy) [px]."""
    fx, fy, cx, cy = intrinsics
    d = np.array([1.0, (cx - u) / fx, (cy - v) / fy])
    return d / np.linalg.norm(d)


def centre(points: np.ndarray, ray: np.ndarray, fx: float, cfg: CloudConfig) -> Centre | str:
    """Robust ball centre on the viewing ray ``ray`` (unit, (3,)) from surface points (N, 3) [m].

    Each finite point ``p`` on the sphere of radius ``r`` whose centre lies at distance ``D``
    along ``ray`` gives ``D = p.ray + sqrt(r^2 - l^2)``, ``l`` its distance from the ray (the
    root 0 when ``l > r``: a point off the ball). So the box need not hold only the ball's middle,
    and the ball's own depth is accounted for wherever in the box the valid pixels are.

    The inliers are the nearest group of those ``D`` with enough support: at least
    ``min_group`` points, and ``group_fraction`` of the largest group, within a gate of
    ``max(gate_sigmas * D^2 disparity_sigma / (fx B), min_gate)`` (the ball hides what is
    behind it; at long range a small box's corners and edge pixels can outnumber the ball's,
    and a median of all points would land between the ball and the scene behind it). The
    centre is at the median ``D`` of the points within the gate of it, re-centred until it
    stays put (at most 3 times).

    Args:
        points: surface points in ``camera`` [m] (N, 3) (non-finite rows are skipped).
        ray: unit viewing ray of the ball's image centre (3,).
        fx: focal length [px] (sets the stereo noise of the gate).
        cfg: parameters.

    Returns:
        A :class:`Centre`, or the reason there is none: ``"no_depth"`` (fewer than
        ``min_valid`` finite points, or no group of ``min_group``) or ``"out_of_range"``.
    """
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(points).all(axis=1) & (points[:, 0] > 0.0)
    pts = points[ok].astype(np.float64)
    n = len(pts)
    if n < cfg.min_valid:
        return "no_depth"
    along = pts @ ray
    off2 = np.maximum((pts * pts).sum(axis=1) - along * along, 0.0)
    dist = np.sort(along + np.sqrt(np.maximum(cfg.ball_radius**2 - off2, 0.0)))
    gate = np.maximum(
        cfg.gate_sigmas * dist**2 * cfg.disparity_sigma / (fx * cfg.baseline), cfg.min_gate
    )
    lo = np.searchsorted(dist, dist - gate, side="left")
    hi = np.searchsorted(dist, dist + gate, side="right")
    count = hi - lo
    enough = count >= max(cfg.min_group, cfg.group_fraction * count.max())
    if not enough.any():  # scattered points, no two agree
        return "no_depth"
    best = int(np.argmax(enough))  # the nearest group with enough support
    inl = dist[lo[best] : hi[best]]
    d = float(np.median(inl))
    for _ in range(3):  # re-centre on that group (a blur trail spreads the ball in depth)
        g = max(cfg.gate_sigmas * d * d * cfg.disparity_sigma / (fx * cfg.baseline), cfg.min_gate)
        near = dist[np.searchsorted(dist, d - g) : np.searchsorted(dist, d + g, side="right")]
        if len(near) == 0:
            break
        inl, before, d = near, d, float(np.median(near))
        if d == before:
            break
    spread = 1.4826 * float(np.median(np.abs(inl - d)))
    pos = ray * d
    if not cfg.min_range <= pos[0] <= cfg.max_range:
        return "out_of_range"
    k = len(inl)
    conf = (k / (k + cfg.count_half)) / (1.0 + (spread / cfg.spread_half) ** 2)
    return Centre(pos, n, k, spread, float(min(1.0, max(0.0, conf))))
