"""Small linear algebra summed in one fixed order, so every machine gets the same last bit.

numpy's ``@``, ``np.dot``, ``np.linalg.norm`` of a vector and ``np.linalg.solve`` call BLAS and
LAPACK, whose kernel is picked at run time for the CPU (``OPENBLAS_CORETYPE``): the same product
is summed in another order, or with fused multiply-adds, on another machine, and a compiled tree
came out different where a distance sat on a threshold. These functions use only elementwise
multiplies and adds (each exactly rounded by IEEE 754, never fused by numpy) in the order of the
inner index 0, 1, 2, ..., and a pivoted elimination in Python floats for the small solves: the
same inputs give the same bits whatever BLAS is loaded. Meant for 3 x 3 to 6 x 6 work; shapes
broadcast as for ``@``. Units are the caller's.

numpy's ``arccos`` and ``arctan2`` (and ``exp``, ``log``, ``power`` ...) are dispatched at run
time too: on a CPU with AVX-512 numpy takes its own vector code, which differs from the C
library's in the last bit (about one value in ten); elsewhere it calls the C library.
:func:`arccos` and :func:`arctan2` call the C library (Python's ``math``) on every machine.
"""

from __future__ import annotations

import math

import numpy as np


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for (..., m, k) and (..., k, n) (stacks broadcast), or a vector on either side."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if b.ndim == 1:
        return matvec(a, b)
    if a.ndim == 1:
        out = a[0] * b[..., 0, :]
        for j in range(1, a.shape[-1]):
            out = out + a[j] * b[..., j, :]
        return out
    out = a[..., :, 0:1] * b[..., 0:1, :]
    for j in range(1, a.shape[-1]):
        out += a[..., :, j : j + 1] * b[..., j : j + 1, :]
    return out


def matvec(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``a @ v`` for matrices (..., m, k) and vectors (..., k): (..., m)."""
    a, v = np.asarray(a, dtype=np.float64), np.asarray(v, dtype=np.float64)
    out = a[..., :, 0] * v[..., None, 0]
    for j in range(1, a.shape[-1]):
        out = out + a[..., :, j] * v[..., None, j]
    return out


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Inner products over the last axis (shapes broadcast): ``(a * b).sum(-1)`` in order."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    out = a[..., 0] * b[..., 0]
    for j in range(1, max(a.shape[-1], b.shape[-1])):
        out = out + a[..., j] * b[..., j]
    return out


def norm(x: np.ndarray) -> np.ndarray:
    """Euclidean norms over the last axis."""
    return np.sqrt(dot(x, x))


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x`` with ``a x = b`` for one small float64 system (n, n), (n,), by Gaussian elimination
    with partial pivoting (the first largest pivot) in Python floats.

    Raises:
        numpy.linalg.LinAlgError: ``a`` is singular (a zero pivot) or the result is not finite.
    """
    n = len(b)
    m = [
        row + [bi]
        for row, bi in zip(
            np.asarray(a, float).tolist(), np.asarray(b, float).tolist(), strict=True
        )
    ]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        if m[p][c] == 0.0:
            raise np.linalg.LinAlgError("Singular matrix")
        m[c], m[p] = m[p], m[c]
        top = m[c]
        for r in range(c + 1, n):
            row = m[r]
            f = row[c] / top[c]
            if f != 0.0:
                for k in range(c, n + 1):
                    row[k] -= f * top[k]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        row, s = m[r], m[r][n]
        for k in range(r + 1, n):
            s -= row[k] * x[k]
        x[r] = s / row[r]
    out = np.array(x)
    if not np.isfinite(out).all():
        raise np.linalg.LinAlgError("Singular matrix")
    return out


def arccos(x: np.ndarray) -> np.ndarray:
    """``np.arccos`` of ``x`` (any shape, within [-1, 1]) by the C library's ``acos``, element by
    element: the same bits on every CPU (numpy's AVX-512 code differs in the last bit)."""
    x = np.asarray(x, dtype=np.float64)
    flat = [math.acos(v) for v in x.ravel().tolist()]
    return np.array(flat, dtype=np.float64).reshape(x.shape)


def arctan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``np.arctan2(y, x)`` (shapes broadcast) by the C library's ``atan2``, element by element."""
    y, x = np.broadcast_arrays(np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64))
    flat = [math.atan2(a, b) for a, b in zip(y.ravel().tolist(), x.ravel().tolist(), strict=True)]
    return np.array(flat, dtype=np.float64).reshape(y.shape)
