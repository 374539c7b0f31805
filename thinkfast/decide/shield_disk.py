"""Probability mass of the crossing point inside each goal's disk, resolved along one direction.

Used by :mod:`thinkfast.decide.values`. The crossing belief ``(Y, Z, tau) ~ N(m, S)`` is
rewritten in a frame of the plane where tau's regression on (Y, Z) varies along ``u`` only:

    tau = m_tau + beta U + eps,   eps ~ N(0, s_c^2) independent of (U, W),
    U ~ N(0, s_u^2),   W | U ~ N(gamma U, s_wc^2),

(U, W centred at the mean). For a disk centred at (c_u, c_w) of radius r, the chord at
``u = c_u + r v`` is ``c_w +- r sqrt(1 - v^2)``, so ``P(W in chord | U = u)`` is two Phi. The
integral over u uses the substitution ``v = (3 s - s^3) / 2`` (``dv/ds = 0`` at ``s = +-1``, so the
square-root ends of the chord become smooth) and Gauss-Legendre on up to three pieces: the disk
clipped to ``+-k_sigma s_u``, split where the line ``w = gamma u`` crosses the circle, since a
narrow W | U switches the chord probability there.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


class PlaneFrame(NamedTuple):
    """The crossing belief in the (u, w) frame of the plane (see the module docstring).

    Attributes:
        m_yz: mean (Y, Z) [m], shape (2,).
        e_u, e_w: unit vectors of u and w in (y, z), shape (2,) each.
        beta: slope of E[tau | U] [s/m], >= 0.
        s_c2: variance of tau given (Y, Z) [s^2].
        s_u, s_w: marginal standard deviations of U and W [m].
        gamma: slope of E[W | U]; s_wc: standard deviation of W given U [m].
    """

    m_yz: np.ndarray
    e_u: np.ndarray
    e_w: np.ndarray
    beta: float
    s_c2: float
    s_u: float
    s_w: float
    gamma: float
    s_wc: float


class DiskNodes(NamedTuple):
    """Quadrature nodes: one row of n nodes per piece of a disk that is not pruned (P rows).

    Attributes:
        goals: the goals not pruned, ascending, shape (A,).
        row: for each piece, its goal's position in ``goals``, shape (P,); one to three pieces
            per goal.
        mass: probability mass of each node's cell, shape (P, n).
        tau_lo, tau_hi: ``beta U`` at the ends of each cell [s] (tau minus its mean), (P, n).
    """

    goals: np.ndarray
    row: np.ndarray
    mass: np.ndarray
    tau_lo: np.ndarray
    tau_hi: np.ndarray


def plane_frame(o_mean: np.ndarray, o_cov: np.ndarray) -> PlaneFrame:
    """Decompose N(o_mean, o_cov) of (Y [m], Z [m], tau [s]); ``o_cov`` shape (3, 3)."""
    (a, b, cy), (_, d, cz), (_, _, tt) = o_cov.tolist()
    a += 1e-12  # a 1 um floor keeps the (Y, Z) block invertible
    d += 1e-12
    det = a * d - b * b
    by, bz = (d * cy - b * cz) / det, (a * cz - b * cy) / det  # regression of tau on (Y, Z)
    beta = math.hypot(by, bz)
    uy, uz = (by / beta, bz / beta) if beta > 1e-12 else (1.0, 0.0)
    su2 = uy * uy * a + 2.0 * uy * uz * b + uz * uz * d
    suw = uy * (-uz) * a + (uy * uy - uz * uz) * b + uz * uy * d
    sw2 = uz * uz * a - 2.0 * uy * uz * b + uy * uy * d
    gamma = suw / su2
    return PlaneFrame(
        m_yz=np.array(o_mean[:2], dtype=float),
        e_u=np.array([uy, uz]),
        e_w=np.array([-uz, uy]),
        beta=beta,
        s_c2=max(tt - (by * cy + bz * cz), 1e-14),
        s_u=math.sqrt(su2),
        s_w=math.sqrt(sw2),
        gamma=gamma,
        s_wc=math.sqrt(max(sw2 - suw * gamma, 1e-14)),
    )


def disk_nodes(frame: PlaneFrame, goal_yz: np.ndarray, radius: float, cfg) -> DiskNodes | None:
    """Node masses of every goal disk that can hold more than ``2 Q(k_sigma)``; None if none.

    Args:
        frame: from :func:`plane_frame`.
        goal_yz: goal centres (y, z) [m], shape (G, 2).
        radius: shield radius r [m].
        cfg: a ValueConfig (k_sigma, min_nodes, max_nodes, nodes_per_sigma, cell_sigma).
    """
    r = radius
    cuw = (goal_yz - frame.m_yz) @ np.column_stack([frame.e_u, frame.e_w])
    cu, cw = cuw[:, 0], cuw[:, 1]
    ku, kw = cfg.k_sigma * frame.s_u, cfg.k_sigma * frame.s_w
    alive = np.flatnonzero((np.abs(cu) < ku + r) & (np.abs(cw) < kw + r))
    if alive.size == 0:
        return None
    cu, cw = cu[alive], cw[alive]
    # Piece ends in v = (u - c_u) / r: the +-k sigma clip and, where W | U is narrower than the
    # disk, the crossings of w = gamma u with the circle. Each non-empty piece is one row.
    knots_v = np.empty((len(alive), 4))
    knots_v[:, 0] = (-ku - cu) / r
    knots_v[:, 3] = (ku - cu) / r
    np.clip(knots_v[:, ::3], -1.0, 1.0, out=knots_v[:, ::3])
    if frame.s_wc < r:
        knots_v[:, 1:3] = _crossings(cu, cw, frame.gamma, r)
        np.maximum(knots_v[:, 1:3], knots_v[:, :1], out=knots_v[:, 1:3])
        np.minimum(knots_v[:, 1:3], knots_v[:, 3:], out=knots_v[:, 1:3])
    else:
        knots_v[:, 1:3] = knots_v[:, 3:]
    width_v = knots_v[:, 1:] - knots_v[:, :-1]  # (A, 3)
    a_idx, p_idx = np.nonzero(width_v > 0.0)
    if a_idx.size == 0:
        return None
    knots = 2.0 * np.sin(np.arcsin(knots_v) * (1.0 / 3.0))  # s with (3 s - s^3) / 2 = v
    s_lo = knots[a_idx, p_idx][:, None]
    s_len = knots[a_idx, p_idx + 1][:, None] - s_lo
    row_cu = cu[a_idx][:, None]

    # Nodes per piece: nodes_per_sigma per scale of the integrand along u (sigma_u, and the
    # chord's own scale s_wc / |gamma| as E[W | U] sweeps across w); cells narrow enough that
    # their tau spread beta * cell stays below s_c (or below cell_sigma s_u); and finer than the
    # chord's switch where w = gamma u grazes a circle, about sqrt(2 r s_wc) wide.
    longest = r * float(width_v.max())
    scale = min(frame.s_u, frame.s_wc / max(abs(frame.gamma), 1e-300))
    cell_u = min(
        max(math.sqrt(frame.s_c2) / max(frame.beta, 1e-300), cfg.cell_sigma * frame.s_u),
        0.5 * math.sqrt(2.0 * r * frame.s_wc),
    )
    need = max(cfg.nodes_per_sigma * longest / scale, 0.5 * math.pi * longest / cell_u)
    m = 4 * math.ceil(min(max(need, 1.0), 1e6) / 4.0)
    x, w, cell = _rule(int(min(max(m, cfg.min_nodes), cfg.max_nodes)))

    s = s_lo + s_len * x  # (P, m)
    ss = s * s
    v = s * (3.0 - ss)  # 2 v
    u = row_cu + (0.5 * r) * v
    hw = 1.0 - 0.25 * v * v
    np.maximum(hw, 0.0, out=hw)
    np.sqrt(hw, out=hw)
    hw *= r / frame.s_wc  # half-chord in units of s_wc
    off = cw[a_idx][:, None] * (1.0 / frame.s_wc) - (frame.gamma / frame.s_wc) * u
    chord = ndtr(off + hw)
    chord -= ndtr(off - hw)
    mass = np.exp(u * u * (-0.5 / (frame.s_u * frame.s_u)))
    mass *= chord
    mass *= 1.0 - ss
    mass *= s_len * ((1.5 * r * _INV_SQRT_2PI / frame.s_u) * w)

    s_cell = s_lo + s_len * cell  # (P, m + 1)
    tau_edge = s_cell * (3.0 - s_cell * s_cell)
    tau_edge *= 0.5 * r * frame.beta
    tau_edge += frame.beta * row_cu
    return DiskNodes(alive, a_idx, mass, tau_edge[:, :-1], tau_edge[:, 1:])


def _crossings(cu: np.ndarray, cw: np.ndarray, gamma: float, r: float) -> np.ndarray:
    """v = (u - c_u) / r where the line w = gamma u crosses each circle, sorted, shape (A, 2).

    Rows without a crossing hold +1 twice (no cut).
    """
    a = 1.0 + gamma * gamma
    bh = cu + gamma * cw  # the quadratic is a u^2 - 2 bh u + c = 0
    c = cu * cu + cw * cw - r * r
    disc = bh * bh - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    v = (np.stack([(bh - root) / a, (bh + root) / a], axis=1) - cu[:, None]) / r
    return np.where((disc > 0.0)[:, None], v, 1.0)


@functools.lru_cache(maxsize=32)
def _rule(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1], and cell edges (cumulative weights)."""
    x, w = np.polynomial.legendre.leggauss(m)
    cell = np.concatenate([[0.0], np.cumsum(0.5 * w)])
    cell[-1] = 1.0
    return 0.5 * (x + 1.0), 0.5 * w, cell
