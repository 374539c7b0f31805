"""Ball blobs in a BGR(A) image: HSV colour filter plus morphology, coarse to fine.

Pure (no I/O, no clocks). The whole image is searched on every ``search_step``-th pixel (the
HSV conversion and threshold of a quarter of the pixels cost well under a millisecond at HD720);
each coarse blob is then refined at full resolution in a small window: threshold, opening (drops
specks), closing (fills the ball's highlight and blur holes), largest connected component.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from thinkfast.perception.config import ColourConfig

POOL = 8  # coarse pixels per cell side when grouping the coarse mask into windows


class Blob(NamedTuple):
    """A ball-coloured region.

    Attributes:
        x0, y0, x1, y1: its box in left-image pixels (``x1``, ``y1`` exclusive).
        area: its pixel count.
        u, v: its centroid [px, pixel centres at integers].
        mask: the blob's pixels in its box, shape (y1 - y0, x1 - x0), bool, read-only.
    """

    x0: int
    y0: int
    x1: int
    y1: int
    area: int
    u: float
    v: float
    mask: np.ndarray


def colour_mask(bgr: np.ndarray, cfg: ColourConfig) -> np.ndarray:
    """Mask (H, W) uint8 (255 where the colour is in range) of a (H, W, 3|4) uint8 image."""
    if bgr.shape[2] == 4:
        bgr = cv2.cvtColor(bgr, cv2.COLOR_BGRA2BGR)
    hsv = cv2.cvtColor(np.ascontiguousarray(bgr), cv2.COLOR_BGR2HSV)
    return cv2.inRange(hsv, np.array(cfg.hsv_low, np.uint8), np.array(cfg.hsv_high, np.uint8))


def _morph(mask: np.ndarray, n: int, first, second) -> np.ndarray:
    """Opening (``first=cv2.erode``) or closing (``first=cv2.dilate``) with an n x n kernel.

    The second pass uses the mirrored anchor: with an even ``n`` OpenCV's ``morphologyEx``
    moves the mask by a pixel, which would move the ball's centroid too.
    """
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE if n > 3 else cv2.MORPH_RECT, (n, n))
    a = n // 2
    return second(first(mask, k, anchor=(a, a)), k, anchor=(n - 1 - a, n - 1 - a))


def refine(image: np.ndarray, window: tuple[int, int, int, int], cfg: ColourConfig) -> Blob | None:
    """The largest blob in ``window`` = (x0, y0, x1, y1) of ``image`` at full resolution."""
    x0, y0, x1, y1 = window
    mask = colour_mask(image[y0:y1, x0:x1], cfg)
    if cfg.open_px > 1:
        mask = _morph(mask, cfg.open_px, cv2.erode, cv2.dilate)
    if cfg.close_px > 1:
        mask = _morph(mask, cfg.close_px, cv2.dilate, cv2.erode)
    n, labels, stats, cent = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    bx, by, bw, bh, area = (int(v) for v in stats[k])
    if area < cfg.min_area:
        return None
    u, v = (float(c) for c in cent[k])
    own = labels[by : by + bh, bx : bx + bw] == k
    own.setflags(write=False)
    return Blob(x0 + bx, y0 + by, x0 + bx + bw, y0 + by + bh, area, x0 + u, y0 + v, own)


def find_blobs(image: np.ndarray, cfg: ColourConfig) -> list[Blob]:
    """Ball-coloured blobs of a left image (H, W, 3|4) uint8, largest first.

    The coarse mask is pooled into cells of ``POOL`` coarse pixels; each group of touching cells
    is one window to refine (so the cost does not grow with the image size beyond the coarse
    threshold).

    Returns:
        At most ``cfg.max_candidates`` blobs of at least ``cfg.min_area`` pixels.
    """
    h, w = image.shape[:2]
    s = min(cfg.search_step, w, h)
    if s > 1:  # nearest neighbour: every s-th pixel, like image[::s, ::s] but faster
        # (docs/BENCHMARKS.md, "Kernel figures the code refers to")
        image_s = cv2.resize(image, (w // s, h // s), interpolation=cv2.INTER_NEAREST)
    else:
        image_s = image
    mask = colour_mask(image_s, cfg)
    if not cv2.countNonZero(mask):
        return []
    mh, mw = mask.shape
    padded = cv2.copyMakeBorder(mask, 0, -mh % POOL, 0, -mw % POOL, cv2.BORDER_CONSTANT, value=0)
    cells = cv2.resize(
        padded, (padded.shape[1] // POOL, padded.shape[0] // POOL), interpolation=cv2.INTER_AREA
    )
    n, _, stats, _ = cv2.connectedComponentsWithStats((cells > 0).view(np.uint8), connectivity=8)
    cell = POOL * s
    pad = s + cfg.close_px + cfg.open_px + 2
    windows = []
    for k in range(1, n):
        bx, by, bw, bh = (int(v) for v in stats[k, :4])
        count = cv2.countNonZero(mask[by * POOL : (by + bh) * POOL, bx * POOL : (bx + bw) * POOL])
        window = (
            max(0, bx * cell - pad),
            max(0, by * cell - pad),
            min(w, (bx + bw) * cell + pad),
            min(h, (by + bh) * cell + pad),
        )
        windows.append((count, window))
    windows.sort(key=lambda cw: -cw[0])
    out = [refine(image, win, cfg) for _, win in windows[: cfg.max_candidates]]
    return sorted((b for b in out if b is not None), key=lambda b: -b.area)
