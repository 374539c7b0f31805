"""Probability that an isotropic 2-D Gaussian point falls in a disk, as a fast lookup.

For ``X ~ N(0, sigma^2 I_2)``, a disk of radius ``rho`` and an offset ``d`` of its centre,

    F(d; rho, sigma) = P(|X + d e| <= rho) = 1 - Q_1(d / sigma, rho / sigma)

(Marcum Q; the non-central chi-square CDF with 2 degrees of freedom, ``scipy.special.chndtr``).
It depends on ``b = rho / sigma`` and the distance from the rim in sigmas, ``xi = (d - rho) /
sigma``. One table of ``F(xi; b)`` is built once per process and cached (its cost:
docs/BENCHMARKS.md, "Path values: moving shields"):

- columns: ``xi`` in [-8, 8] every 0.025 (beyond, F is 1 or 0 within 1e-15 for b >= 8; for
  smaller b, ``xi >= -b`` always);
- rows: ``b`` in [0, 16] every 1/16, then ``s = 1 / b`` in [0, 1/16] every 1/128 down to the
  half-plane limit ``F = Phi(-xi)`` at ``s = 0``. In these coordinates F is smooth along the rows
  in both parts.

:func:`disk_profiles` interpolates the rows (cubic Lagrange) at the few ``b`` of one belief update;
callers then interpolate linearly along ``xi``. Errors (tests/test_iso_disk.py, against chndtr):
row interpolation below 1e-5, the column step ``0.025^2 / 8 * max|F''| <= 2e-5``.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.special import chndtr, ndtr

XI_MAX = 8.0
XI_STEP = 0.025
XI = np.linspace(-XI_MAX, XI_MAX, int(round(2 * XI_MAX / XI_STEP)) + 1)
XI.setflags(write=False)
_B_STEP = 1.0 / 16.0
_B_MAX = 16.0
_S_STEP = 1.0 / 128.0  # rows in s = 1 / b from 1 / B_MAX down to 0


def _row(b: float) -> np.ndarray:
    """F(xi; b) at every column; F(xi) = F(|b + xi| sigma) by the symmetry of the disk."""
    if b == 0.0:
        return np.zeros_like(XI)
    t = np.abs(b + XI)
    return np.clip(chndtr(b * b, 2.0, t * t), 0.0, 1.0)


@functools.lru_cache(maxsize=1)
def _tables() -> tuple[np.ndarray, np.ndarray]:
    """Rows in b (b = 0 .. 16) and rows in s = 1 / b (s = 0 .. 1 / 16), each (rows, columns)."""
    rows_b = np.array([_row(b) for b in np.arange(0.0, _B_MAX + 1e-9, _B_STEP)])
    s_grid = np.arange(0.0, 1.0 / _B_MAX + 1e-12, _S_STEP)
    rows_s = np.array([ndtr(-XI) if s == 0.0 else _row(1.0 / s) for s in s_grid])
    for a in (rows_b, rows_s):
        a.setflags(write=False)
    return rows_b, rows_s


def warm_up() -> None:
    """Build the cached table now rather than at the first use (a decision's worth of time)."""
    _tables()


# cubic Lagrange weights of the stencil rows at u = -1, 0, 1, 2 as polynomials: [1 u u^2 u^3] @ C
_LAGRANGE = np.array(
    [
        [0.0, 1.0, 0.0, 0.0],
        [-1.0 / 3.0, -0.5, 1.0, -1.0 / 6.0],
        [0.5, -1.0, 0.5, 0.0],
        [-1.0 / 6.0, 0.5, -0.5, 1.0 / 6.0],
    ]
)


def _lagrange(n: int, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows (P, 4) and weights (P, 4) of cubic Lagrange interpolation at fractional rows ``pos``
    (P,) of a table with ``n`` rows (stencil clamped at the ends)."""
    pos = np.minimum(np.maximum(pos, 0.0), n - 1.0)
    j = np.minimum(np.maximum(pos.astype(np.intp) - 1, 0), n - 4)
    u = pos - j - 1.0
    return j[:, None] + np.arange(4), (u[:, None] ** np.arange(4)) @ _LAGRANGE


def disk_profiles(sigma: float, radii: np.ndarray) -> np.ndarray:
    """``F(xi)`` on the columns :data:`XI` for each radius, shape (L, len(XI)).

    Args:
        sigma: standard deviation of each coordinate [m], > 0.
        radii: disk radii [m], shape (L,), >= 0.
    """
    rows_b, rows_s = _tables()
    b = np.asarray(radii, dtype=float) * (1.0 / sigma)
    small = b <= _B_MAX
    out = np.empty((len(b), len(XI)))
    if np.logical_or.reduce(small):
        idx, w = _lagrange(len(rows_b), b[small] * (1.0 / _B_STEP))
        out[small] = np.matmul(w[:, None, :], rows_b[idx])[:, 0]
    if not np.logical_and.reduce(small):
        idx, w = _lagrange(len(rows_s), (1.0 / b[~small]) * (1.0 / _S_STEP))
        out[~small] = np.matmul(w[:, None, :], rows_s[idx])[:, 0]
    np.clip(out, 0.0, 1.0, out=out)
    return out


def rim_table(sigma: float, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`disk_profiles` as flat value and slope tables for linear lookups.

    Returns:
        ``(value, slope)``, each shape (L * (len(XI) - 1),): row l, column c holds F at column c
        and the step to column c + 1, at ``l * (len(XI) - 1) + c``.
    """
    radii = np.asarray(radii, dtype=float)
    if len(radii) == 1:  # the common case, without the batch machinery
        rows_b, rows_s = _tables()
        b = float(radii[0]) / sigma
        rows, pos, n = (
            (rows_b, b / _B_STEP, len(rows_b))
            if b <= _B_MAX
            else (rows_s, 1.0 / b / _S_STEP, len(rows_s))
        )
        pos = min(max(pos, 0.0), n - 1.0)
        j = min(max(int(pos) - 1, 0), n - 4)
        u = pos - j - 1.0
        prof = np.array([1.0, u, u * u, u * u * u]) @ _LAGRANGE @ rows[j : j + 4]
        np.minimum(np.maximum(prof, 0.0, out=prof), 1.0, out=prof)  # np.clip, no wrapper
        return prof[:-1], prof[1:] - prof[:-1]
    prof = disk_profiles(sigma, radii)
    return prof[:, :-1].ravel(), (prof[:, 1:] - prof[:, :-1]).ravel()  # np.diff, unwrapped


def disk_probability(d: np.ndarray, rho: float, sigma: float) -> np.ndarray:
    """P(|X + d e| <= rho), X ~ N(0, sigma^2 I_2), for distances ``d`` [m] (any shape).

    The lookup the path-value kernel does, for one radius (tests and one-off use).
    """
    prof = disk_profiles(sigma, np.array([rho]))[0]
    xi = (np.asarray(d, dtype=float) - rho) / sigma
    return np.interp(xi, XI, prof)
