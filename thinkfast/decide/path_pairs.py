"""Pair-level kernels of :mod:`thinkfast.decide.path_value`: the crossing belief in the
kernel's terms, the shield at every (path, tau node) pair, and the isotropic disk probability
averaged over the nodes along the belief's major axis.

All pure numpy over arrays of pairs (any shape that broadcasts); no loops over paths. The
kernel calls :func:`conditional`; :func:`cut_cells`, :func:`relative` and :func:`disk_mean` are
the reference of their compiled pass (:mod:`thinkfast.decide.pair_jit`, equal bit for bit),
which the kernel calls instead.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from thinkfast.decide import iso_disk
from thinkfast.decide.shield_paths import BlockGeometry, ShieldPaths
from thinkfast.estimate.linalg import clip

_SIGMA_T_FLOOR = 1e-6  # s
REACH_A = 4.5  # the isotropic disk probability is 1 or 0 within 4e-6 beyond 4.5 sigma of the rim
REACH_Z = 4.0  # nodes beyond 4 sigma along tau or the major axis weigh < 1e-4 in all


class CrossingConditional(NamedTuple):
    """The crossing Gaussian as the kernel uses it (see the module doc)."""

    m_yz: np.ndarray  # (2,) [m]
    m_t: float  # [s]
    sd_t: float  # [s]
    k: np.ndarray  # (2,) slope of E[(Y, Z) | tau] [m/s]
    sig_a: float  # isotropic part of (Y, Z) | tau [m]
    sig_e: float  # excess along e [m]
    e: np.ndarray  # (2,) major axis of (Y, Z) | tau


def conditional(o_mean, o_cov, sigma_floor: float) -> CrossingConditional:
    """The crossing Gaussian N(o_mean, o_cov) of (Y, Z, tau) in the kernel's terms; the lateral
    standard deviations are floored at ``sigma_floor`` [m], tau's at 1 us."""
    (syy, syz, syt), (_, szz, szt), (_, _, stt) = np.asarray(o_cov, dtype=float).tolist()
    var_t = max(stt, _SIGMA_T_FLOOR**2)
    ky, kz = syt / var_t, szt / var_t
    a, c, d = syy - ky * syt, syz - ky * szt, szz - kz * szt  # (Y, Z) | tau: [[a, c], [c, d]]
    half_gap = math.hypot(0.5 * (a - d), c)
    lam0 = max(0.5 * (a + d) - half_gap, sigma_floor**2)
    lam1 = 0.5 * (a + d) + half_gap
    angle = 0.5 * math.atan2(2.0 * c, a - d)  # major axis
    return CrossingConditional(
        np.array([float(o_mean[0]), float(o_mean[1])]),
        float(o_mean[2]),
        math.sqrt(var_t),
        np.array([ky, kz]),
        math.sqrt(lam0),
        math.sqrt(max(lam1 - lam0, 0.0)),
        np.array([math.cos(angle), math.sin(angle)]),
    )


def cut_cells(paths: ShieldPaths, path, start, b: CrossingConditional, z, half):
    """Where a touch-depth crossing falls inside a node's cell (half width ``half`` [s], 0: no
    cell), the node stands for the part of its cell where contact is possible.

    Returns:
        ``(z, share)``: the node to evaluate [sigma_tau] (the middle of the contact part when
        the node itself is on the other side) and the share of the cell it stands for.
    """
    tau = b.m_t + b.sd_t * z
    d = paths.cuts[path] + (start - tau)[:, None]  # (P, K) crossing - node [s]
    k = np.abs(d).argmin(axis=1)
    rows = np.arange(len(z))
    d = d[rows, k]
    entering = paths.cut_in[path, k]
    inside = np.abs(d) < half
    if not np.logical_or.reduce(inside):
        return z, np.ones(len(z))
    node_in = (d < 0.0) == entering  # the node is on the contact side of the crossing
    near = np.zeros(len(z))
    np.divide(np.abs(d), half, out=near, where=inside)
    near += 1.0
    near *= 0.5  # share of the cell on the node's side
    share = np.where(inside, np.where(node_in, near, 1.0 - near), 1.0)
    move = inside & ~node_in  # evaluate in the middle of the other part
    z = z + np.where(move, 0.5 * (d + np.sign(d) * half), 0.0) * (1.0 / b.sd_t)
    return z, share


def relative(paths: ShieldPaths, path, start, b: CrossingConditional, z, geom, approach):
    """The shield at every (path, tau node) pair relative to the conditional mean.

    Args:
        path, start, z: each pair's path, the path's start [s] and the tau node [sigma_tau],
            any shapes that broadcast to the pairs' shape S.

    Returns:
        ``(r_y, r_z, rho, contact)``: the lateral offset [m], each S; the contact radius [m] S,
        or None when every pair has the full radius; whether contact is possible at all (0 or
        1) S, or None when it is everywhere.
    """
    n_t = paths.n_samples
    pos = z * b.sd_t + (b.m_t - paths.t0) - start  # [s] on the paths' clocks
    pos *= 1.0 / paths.dt
    clip(pos, 0.0, n_t - 1.0, out=pos)
    i = pos.astype(np.intp)
    pos -= i
    pos *= paths.dt  # seconds into the segment
    i += path * n_t
    x, y, z_, vx, vy, vz = paths.planes[:, i]  # each of shape S
    dx = vx * pos
    dx += x - geom.plane_x
    r_y = vy * pos
    r_y += y
    r_y -= b.m_yz[0] + (b.k[0] * b.sd_t) * z
    r_z = vz * pos
    r_z += z_
    r_z -= b.m_yz[1] + (b.k[1] * b.sd_t) * z
    if approach is not None:
        ball_vx, ball_vy, ball_vz = (float(v) for v in approach)
        s = vx + abs(ball_vx)
        np.maximum(s, 0.5 * abs(ball_vx), out=s)
        np.divide(np.maximum(dx, 0.0), s, out=s)  # how long before tau the ball meets it [s]
        vy -= ball_vy
        vy *= s
        r_y -= vy
        vz -= ball_vz
        vz *= s
        r_z -= vz
    _, r_shield, h, r_b = geom
    if np.minimum.reduce(dx, axis=None) >= -h:
        return r_y, r_z, None, None
    behind = -dx - h
    clip(behind, 0.0, r_b, out=behind)
    rho = r_b * r_b - behind * behind
    np.sqrt(rho, out=rho)
    rho += r_shield
    contact = (dx >= -(h + r_b)).astype(float)
    return r_y, r_z, rho, contact


def disk_mean(
    r_y, r_z, rho, contact, b: CrossingConditional, eta, w_eta, geom, levels: int
) -> np.ndarray:
    """E over eta of the isotropic disk probability for every pair (any shape S), shape S.

    Pairs farther than every node's reach from the rim are 1 (inside) or 0 (outside); when they
    are many, only the others are looked up.
    """
    shape = r_y.shape
    r_y, r_z = r_y.ravel(), r_z.ravel()
    rho = None if rho is None else rho.ravel()
    d2 = r_y * r_y
    d2 += r_z * r_z
    reach = REACH_A * b.sig_a + min(float(np.maximum.reduce(np.abs(eta))), REACH_Z * b.sig_e)
    if rho is None:  # one radius: bounds as floats
        radius = geom.shield_radius + geom.ball_radius
        inner = max(radius - reach, 0.0)
        inner *= inner
        outer = radius + reach
        outer *= outer
    else:
        inner = np.maximum(rho - reach, 0.0)
        inner *= inner
        outer = rho + reach
        outer *= outer
    band = d2 > inner
    band &= d2 < outer
    n_band = int(np.count_nonzero(band))
    if n_band == 0:
        val = (d2 <= inner).astype(float)
    elif n_band < 0.5 * band.size:
        val = (d2 <= inner).astype(float)
        sel = np.flatnonzero(band)
        rb = None if rho is None else rho[sel]
        ry, rz, d2b = r_y[sel], r_z[sel], d2[sel]
        val[sel] = _lookup(ry, rz, d2b, rb, b, eta, w_eta, geom, levels)
    else:  # the lookup is right everywhere (the table is 1 and 0 at its ends)
        val = _lookup(r_y, r_z, d2, rho, b, eta, w_eta, geom, levels)
    val = val.reshape(shape)
    if contact is not None:
        val *= contact
    return val


@functools.lru_cache(maxsize=8)
def _radii(r_shield: float, r_ball: float, levels: int) -> np.ndarray:
    """The radius levels [m] (levels,) from R to R + r_b (one array per geometry, read-only)."""
    radii = r_shield + r_ball * np.linspace(0.0, 1.0, levels)
    radii.setflags(write=False)
    return radii


def _lookup(
    r_y, r_z, d2, rho, b: CrossingConditional, eta, w_eta, geom: BlockGeometry, levels: int
) -> np.ndarray:
    """Isotropic disk probability averaged over the eta nodes for pairs of any shape S (offsets
    r_y, r_z [m], squared distance d2, radius rho or None for the full one), shape S."""
    n_col = len(iso_disk.XI)
    scale = 1.0 / (b.sig_a * iso_disk.XI_STEP)
    zero = iso_disk.XI_MAX / iso_disk.XI_STEP  # column of the rim
    r_shield, r_ball = geom.shield_radius, geom.ball_radius
    if rho is None:
        radii = np.array([r_shield + r_ball])
        offset = zero - radii[0] * scale
    else:
        radii = _radii(r_shield, r_ball, levels)
        offset = (zero - rho * scale)[..., None]
    if len(eta) == 1 and eta[0] == 0.0:
        d = np.sqrt(d2)[..., None]
    else:
        proj = r_y * b.e[0]
        proj += r_z * b.e[1]
        d = np.multiply.outer(proj, -2.0 * eta)  # (S, E)
        d += eta * eta
        d += d2[..., None]
        np.maximum(d, 0.0, out=d)
        np.sqrt(d, out=d)
    d *= scale
    d += offset
    clip(d, 0.0, n_col - 1.0 - 1e-9, out=d)
    ci = np.floor(d)
    d -= ci
    ci = ci.astype(np.intp)
    value, slope = iso_disk.rim_table(b.sig_a, radii)
    if rho is None:
        f = slope.take(ci)
        f *= d
        f += value.take(ci)
        return f @ w_eta
    # radius levels from R to R + r_b, interpolated at the same distance from the rim
    lev = (rho - r_shield) * ((levels - 1) / r_ball)
    li = np.minimum(lev.astype(np.intp), levels - 2)
    lev -= li
    ci += (li * (n_col - 1))[..., None]
    f0 = slope.take(ci)
    f0 *= d
    f0 += value.take(ci)
    ci += n_col - 1
    f1 = slope.take(ci)
    f1 *= d
    f1 += value.take(ci)
    f1 -= f0
    f1 *= lev[..., None]
    f0 += f1
    return f0 @ w_eta
