"""Compiled packing of sampled shield paths (:func:`thinkfast.decide.shield_paths.pack`): one
pass per path instead of tens of numpy calls on small arrays.

The same IEEE operations as the numpy packing (kept as ``shield_paths.pack_numpy``, the
reference) in the same order, so the packed arrays are equal bit for bit
(tests/test_pair_jit.py); numba without fastmath. Compiled on first use and cached on disk
(``cache=True``); :func:`thinkfast.decide.pair_jit.warm_up` compiles or loads it ahead. Pure
computation.
Imported only in a process that chose the compiled kernels
(:mod:`thinkfast.robot.kernels`).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def pack_kernel(times, planes, n_t, plane_x, touch_x, max_cuts):
    """Fill the velocity rows ``planes[3:]`` (6, M * T) and return per path: lateral speed
    (M,), box (4, M), front (M,), x range (M, 2), x speed (M,), touch-depth crossings (M, K),
    their (y, z) (M, K, 2) and directions (M, K) (see ``ShieldPaths``)."""
    m = planes.shape[1] // n_t
    inv_dt = 1.0 / (times[1] - times[0]) if n_t > 1 else 1.0
    speed = np.empty(m)
    box = np.empty((4, m))
    front = np.empty(m)
    x_range = np.empty((m, 2))
    x_speed = np.empty(m)
    cuts = np.full((m, max_cuts), np.inf)
    cut_yz = np.full((m, max_cuts, 2), np.nan)
    cut_in = np.zeros((m, max_cuts), dtype=np.bool_)
    for p in range(m):
        o = p * n_t
        lat, xs = 0.0, 0.0  # the held last sample's speeds
        lo = [planes[0, o], planes[1, o], planes[2, o]]
        hi = [planes[0, o], planes[1, o], planes[2, o]]
        count = 0
        for i in range(n_t):
            j = o + i
            for c in range(3):
                v = planes[c, j]
                lo[c] = min(lo[c], v)
                hi[c] = max(hi[c], v)
            if i == n_t - 1:
                for c in range(3, 6):
                    planes[c, j] = 0.0
                continue
            for c in range(3):
                planes[3 + c, j] = (planes[c, j + 1] - planes[c, j]) * inv_dt
            vy, vz = planes[4, j], planes[5, j]
            la = vy * vy
            la += vz * vz
            lat = max(lat, la)
            xs = max(xs, abs(planes[3, j]))
            d0 = planes[0, j] - touch_x
            d1 = planes[0, j + 1] - touch_x
            if (d0 >= 0.0) != (d1 >= 0.0):
                if count < max_cuts:
                    u = d0 / (d0 - d1)
                    cuts[p, count] = times[i] + (times[i + 1] - times[i]) * u
                    for c in range(2):
                        y0, y1 = planes[1 + c, j], planes[1 + c, j + 1]
                        cut_yz[p, count, c] = y0 + (y1 - y0) * u
                    cut_in[p, count] = d1 >= 0.0
                count += 1
        if count > max_cuts:
            cuts[p, 0] = -np.inf
        speed[p] = np.sqrt(lat)
        box[0, p], box[1, p], box[2, p], box[3, p] = lo[1], lo[2], hi[1], hi[2]
        front[p] = max(hi[0] - plane_x, 0.0)
        x_range[p, 0], x_range[p, 1] = lo[0], hi[0]
        x_speed[p] = xs
    return speed, box, front, x_range, x_speed, cuts, cut_yz, cut_in
