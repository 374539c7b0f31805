"""The shield centres' row pass of :meth:`thinkfast.robot.shield_path.ShieldSampler.centre_rows`,
compiled: the chain sample by sample instead of numpy rows.

The same IEEE operations in the same order as the numpy rows (numba without fastmath), so the
centres are equal bit for bit (tests/test_shield_path.py). Imported only when the compiled
kernels are chosen (:mod:`thinkfast.robot.kernels`). Compiled on first use and cached on disk
(``cache=True``); :func:`warm_up` compiles or loads it ahead. Pure computation.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def chain_rows(point, rot_i, rot_j, rot_q, neg, has_t0, t0, trig, off, out):
    """:meth:`ShieldSampler._wrist_rows` plus the offset, sample by sample: the same IEEE
    operations in the same order (numba without fastmath), ``trig`` (2, 3, N) the cos and sin
    of joints 1-3 from numpy; writes ``out`` (3, N)."""
    p = np.empty(3)
    for m in range(out.shape[1]):
        p[0], p[1], p[2] = point[0], point[1], point[2]
        for st in range(len(rot_i)):
            k = rot_q[st]
            if k >= 0:
                c, s = trig[0, k, m], trig[1, k, m]
                if neg[st]:
                    s = -s
                i, j = rot_i[st], rot_j[st]
                pi, pj = p[i], p[j]
                p[i] = c * pi - s * pj
                p[j] = s * pi + c * pj
            if has_t0[st]:
                p[0], p[1], p[2] = p[0] + t0[st, 0], p[1] + t0[st, 1], p[2] + t0[st, 2]
        out[0, m], out[1, m], out[2, m] = p[0] + off[0], p[1] + off[1], p[2] + off[2]


def warm_up() -> None:
    """Compile the row pass (or load it from numba's disk cache) now, with its call types."""
    steps = np.zeros(1, dtype=np.intp)
    flags = np.zeros(1, dtype=np.bool_)
    out = np.empty((6, 1))[:3]  # rows of the packed planes, as the chooser passes them
    chain_rows(np.zeros(3), steps, steps + 1, steps, flags, flags, np.zeros((1, 3)),
               np.zeros((2, 3, 1)), np.zeros(3), out)  # fmt: skip
