"""Quadrature rules for E[f(Z)], Z ~ N(0, 1), chosen from how fast f varies.

f is a Gaussian-blurred profile: it varies on a *scale* (in units of Z) below which it is smooth.
Smooth integrands (scale >= 1) take Gauss-Hermite with few nodes; sharper ones the trapezoid rule
over ``+-k_sigma``, which is spectrally accurate for such integrands (its error falls like
``exp(-2 pi^2 scale^2 / h^2)`` with the spacing h). The Gauss-Hermite node counts per scale and
a trapezoid spacing of 1.25 scales integrate a Gaussian-blurred step of that scale to within
2e-4, a spacing of 1.5 scales (the path-value default) to within 1e-3 (tests/test_path_value.py).
An integrand with a jump (a step not blurred) takes the trapezoid rule with a bounded spacing;
the caller then shares each node's cell at the jump (O(h^2) instead of O(h)), see :func:`cells`.
"""

from __future__ import annotations

import functools
import math

import numpy as np

# (smallest scale, Gauss-Hermite nodes); below the last scale the trapezoid rule takes over
GAUSS_HERMITE = ((20.0, 1), (4.0, 2), (2.0, 3), (1.2, 5), (1.0, 6))
_SQRT_2PI = math.sqrt(2.0 * math.pi)


def normal_rule(
    scale: float,
    max_nodes: int,
    step_ratio: float,
    k_sigma: float,
    jump_step: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights (summing to 1), each shape (n,), for E[f(Z)].

    Args:
        scale: scale of f in units of Z (inf: f constant).
        max_nodes: most nodes (beyond it the rule is coarser and less accurate).
        step_ratio: trapezoid spacing per scale.
        k_sigma: half-width of the trapezoid rule.
        jump_step: f jumps somewhere: trapezoid rule with spacing at most this.
    """
    if jump_step is None:
        for limit, n in GAUSS_HERMITE:
            if scale >= limit:
                return _hermite(min(n, max_nodes))
        step = step_ratio * scale
    else:
        step = min(step_ratio * scale, jump_step)
    half = min(max(1, math.ceil(k_sigma / step)), (max_nodes - 1) // 2)
    if half < 1:
        return _hermite(1)
    return _trapezoid(half, k_sigma)


def cells(nodes: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Width (in units of Z) of the cell each node stands for: weight / density at the node."""
    return weights * _SQRT_2PI * np.exp(0.5 * nodes * nodes)


@functools.lru_cache(maxsize=16)
def _hermite(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.hermite_e.hermegauss(n)
    return _frozen(x, w / w.sum())


@functools.lru_cache(maxsize=256)
def _trapezoid(half: int, k_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(-half, half + 1) * (k_sigma / half)
    w = np.exp(-0.5 * x * x)
    return _frozen(x, w / w.sum())


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for a in arrays:
        a.setflags(write=False)
    return arrays
