"""``np.linalg.inv`` for the small matrices of a decision, without the wrapper's overhead.

``np.linalg.inv`` checks its input, picks a type signature and sets an error state around one
LAPACK call (``gesv`` against the identity): tens of microseconds for a 2 x 2 or 3 x 3 matrix,
most of it not the solve. :func:`inv` makes the same LAPACK call (numpy's own gufunc, the one
``np.linalg.inv`` calls), so its results are those of ``np.linalg.inv`` bit for bit; a result
that is not finite (a singular matrix; numpy warns of the invalid value first) is left to
``np.linalg.inv``, which raises as before. :func:`clip` is ``np.clip``'s ufunc without its
Python wrapper (the same selection of ``x``, ``lo`` or ``hi``, in one pass). Pure computation.
"""

from __future__ import annotations

import numpy as np

try:  # np.clip's ufunc: min(max(x, lo), hi) in one pass, without np.clip's Python wrapper
    from numpy._core.umath import clip
except ImportError:  # pragma: no cover

    def clip(x, lo, hi, out=None):
        return np.minimum(np.maximum(x, lo, out=out), hi, out=out)


try:  # the gufunc behind np.linalg.inv (absent in some numpy: np.linalg.inv itself)
    from numpy.linalg._umath_linalg import inv as _lapack_inv
except ImportError:  # pragma: no cover
    _lapack_inv = None


def inv(a: np.ndarray) -> np.ndarray:
    """Inverse of float64 ``a`` (..., n, n), as ``np.linalg.inv``.

    Raises:
        numpy.linalg.LinAlgError: ``a`` is singular (from ``np.linalg.inv``).
    """
    a = np.asarray(a, dtype=float)
    if _lapack_inv is not None and a.ndim >= 2 and a.shape[-1] == a.shape[-2]:
        out = _lapack_inv(a, signature="d->d")
        if np.isfinite(out).all():
            return out
    return np.linalg.inv(a)
