"""Compiled passes over a whole tree: the terminal values' table lookup
(:func:`thinkfast.decide.values.terminal_values`) and the backup
(:func:`thinkfast.decide.backup.backup`), one loop each instead of several numpy passes over
arrays of up to 10^6 edges.

The lookup makes the numpy code's IEEE operations in the same order (numba without fastmath),
so its values are equal bit for bit; the backup takes maxima, which are exact whatever the
order, so its values are equal too (tests/test_tree_jit.py, against the numpy code kept as
the reference). Compiled on first use and cached on disk (``cache=True``); :func:`warm_up`
compiles or loads them ahead. Pure computation.
Imported only in a process that chose the compiled kernels
(:mod:`thinkfast.robot.kernels`).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def terminal_lookup(remaining, shift, inv_step, top, flat, f, df):
    """Per terminal edge, F at its time on the grid: ``pos = clip((remaining + shift) *
    inv_step, 0, top)``, linear between the table points ``f`` (flat (G * K,)) with steps
    ``df``, row offsets ``flat`` (T,); shape (T,)."""
    n = len(remaining)
    out = np.empty(n)
    for j in range(n):
        p = remaining[j] + shift
        p *= inv_step
        p = min(max(p, 0.0), top)
        i = int(p)
        p -= i
        i += flat[j]
        v = df[i] * p
        v += f[i]
        out[j] = v
    return out


@numba.njit(cache=True, nogil=True)
def backup_values(term_value, child_start, child_count, term_start, term_count):
    """Node values, best child values and best own terminal values (0 where none), each (N,),
    for nodes in breadth-first order (every child after its parent)."""
    n = len(child_count)
    value = np.zeros(n)
    cv = np.zeros(n)
    tv = np.zeros(n)
    for node in range(n - 1, -1, -1):
        if term_count[node] > 0:
            tv[node] = _range_max(term_value, term_start[node], term_count[node])
        v = tv[node]
        if child_count[node] > 0:
            cv[node] = _range_max(value, child_start[node], child_count[node])
            v = max(v, cv[node])
        value[node] = v
    return value, cv, tv


@numba.njit(cache=True, nogil=True, inline="always")
def _range_max(a, start, count):
    """The largest of ``a[start : start + count]`` (``count`` >= 1), first to last."""
    best = a[start]
    for k in range(start + 1, start + count):
        best = max(best, a[k])
    return best


def warm_up() -> None:
    """Compile the kernels (or load them from the disk cache) now, with the types every call
    uses (float64 and intp arrays)."""
    one = np.zeros(1, dtype=np.intp)
    terminal_lookup(np.zeros(1), 0.0, 1.0, 1.0, one, np.zeros(2), np.zeros(2))
    backup_values(np.zeros(1), one, one, one, one + 1)
