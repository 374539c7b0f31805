"""Compiled pair kernels of :mod:`thinkfast.decide.path_value`: one pass over the (path, tau
node) pairs instead of tens of numpy calls on small arrays.

:func:`pair_values` is :func:`~thinkfast.decide.path_pairs.cut_cells`, then
:func:`~thinkfast.decide.path_pairs.relative`, then
:func:`~thinkfast.decide.path_pairs.disk_mean` (those numpy functions stay the reference): the
same IEEE operations in the same order, element by element (numba without fastmath: no
reassociation, no fused multiply-adds), so the values are the reference's bit for bit
(tests/test_pair_jit.py). The sums over the eta nodes stay numpy matrix products, as there.

The kernels are compiled on first use and cached on disk (numba's ``cache=True``: next to this
file, or numba's user cache directory when that is read-only); :func:`warm_up` compiles or loads
them ahead (the chooser calls it when it is made, not in its first decision). Pure computation.
Imported only in a process that chose the compiled kernels
(:mod:`thinkfast.robot.kernels`).
"""

from __future__ import annotations

import numba
import numpy as np

from thinkfast.decide import iso_disk
from thinkfast.decide.path_pairs import REACH_A, REACH_Z, CrossingConditional, _radii
from thinkfast.decide.shield_paths import BlockGeometry, ShieldPaths
from thinkfast.robot import shield_jit, traj_jit

_NONE = np.zeros(0)  # an absent optional array (writable: the same numba type as the others)


def pair_values(
    paths: ShieldPaths,
    path: np.ndarray,
    start: np.ndarray,
    z: np.ndarray,
    outer: bool,
    b: CrossingConditional,
    geom: BlockGeometry,
    approach,
    half: np.ndarray | None,
    eta: np.ndarray,
    w_eta: np.ndarray,
    levels: int,
) -> np.ndarray:
    """E over eta of the isotropic disk probability at every (path, tau node) pair, times the
    contact (and the cell share), flat.

    Args:
        paths: the packed paths.
        path, start: each pair's path (intp) and its start [s], shape (P,).
        z: tau nodes [sigma_tau]: shape (Q,) with ``outer`` (pairs P x Q, path-major), else
            (P,) (one node per pair).
        b, geom, approach: as :func:`~thinkfast.decide.path_pairs.relative`.
        half: half width [s] of each pair's cell (P,) (:func:`cut_cells`), or None (no cells).
        eta, w_eta: nodes [m] and weights along the major axis, shape (E,).
        levels: radius levels behind the plane.

    Returns:
        Shape (P * Q,) with ``outer``, else (P,).
    """
    d2, base, contact, rho, sel, has_rho, r_y, r_z = _relative(
        paths.planes,
        paths.n_samples,
        paths.t0,
        paths.dt,
        np.asarray(path, dtype=np.intp),
        np.asarray(start, dtype=float),
        np.array(z, dtype=float),  # a copy: writable, as every array here (one compilation)
        outer,
        b.m_t,
        b.sd_t,
        float(b.m_yz[0]),
        float(b.m_yz[1]),
        float(b.k[0]) * b.sd_t,
        float(b.k[1]) * b.sd_t,
        geom.plane_x,
        geom.shield_radius,
        geom.half_thickness,
        geom.ball_radius,
        _NONE if approach is None else np.array(approach, dtype=float),
        paths.cuts,
        paths.cut_in,
        _NONE if half is None else half,
        REACH_A * b.sig_a + min(float(np.maximum.reduce(np.abs(eta))), REACH_Z * b.sig_e),
    )
    n_sel = len(sel)
    if n_sel == 0:
        val = base
    else:
        every = n_sel >= 0.5 * len(d2)  # the lookup is right everywhere (table 1 and 0 at its ends)
        r_shield, r_ball = geom.shield_radius, geom.ball_radius
        radii = _radii(r_shield, r_ball, levels) if has_rho else np.array([r_shield + r_ball])
        value, slope = iso_disk.rim_table(b.sig_a, radii)
        f = _lookup(
            r_y, r_z, d2, rho, sel, every, has_rho, b.sig_a, float(b.e[0]), float(b.e[1]),
            np.asarray(eta, dtype=float), value, slope, r_shield, r_ball, levels,
            len(iso_disk.XI), iso_disk.XI_MAX, iso_disk.XI_STEP,
        )  # fmt: skip
        if every:
            val = f @ w_eta
        else:
            val = base
            val[sel] = f @ w_eta
    val *= contact
    return val


@numba.njit(cache=True, nogil=True)
def _relative(
    planes, n_t, t0, dt, path, start, z, outer, m_t, sd_t, m_y, m_z, ky_sd, kz_sd,
    plane_x, r_shield, h, r_b, approach, cuts, cut_in, half, reach,
):  # fmt: skip
    """cut_cells + relative + disk_mean's bounds: per pair the squared offset d2, the value
    where no lookup is needed (0 or 1), contact x share, the contact radius, the pairs to look
    up (ascending), whether radii vary, and the offsets r_y, r_z."""
    n_q = len(z) if outer else 1
    n = len(path) * n_q
    zz = np.empty(n)
    st = np.empty(n)
    pp = np.empty(n, dtype=np.intp)
    for j in range(n):
        p = j // n_q if outer else j
        pp[j] = path[p]
        st[j] = start[p]
        zz[j] = z[j % n_q] if outer else z[j]
    share = np.ones(n)
    if len(half) > 0:  # cut_cells
        d = np.empty(n)
        ent = np.zeros(n, dtype=np.bool_)
        any_inside = False
        n_cut = cuts.shape[1]
        for j in range(n):
            tau = m_t + sd_t * zz[j]
            best, kb = np.inf, 0
            for k in range(n_cut):
                dk = cuts[pp[j], k] + (st[j] - tau)
                if abs(dk) < best:
                    best, kb = abs(dk), k
            dk = cuts[pp[j], kb] + (st[j] - tau)
            d[j] = dk
            ent[j] = cut_in[pp[j], kb]
            if abs(dk) < half[j]:
                any_inside = True
        if any_inside:
            inv_sd = 1.0 / sd_t
            for j in range(n):
                dj = d[j]
                if abs(dj) < half[j]:
                    near = abs(dj) / half[j]
                    near += 1.0
                    near *= 0.5
                    if (dj < 0.0) == ent[j]:  # the node is on the contact side
                        share[j] = near
                        shift = 0.0
                    else:
                        share[j] = 1.0 - near
                        sg = 1.0 if dj > 0.0 else (-1.0 if dj < 0.0 else 0.0)
                        shift = 0.5 * (dj + sg * half[j])
                else:
                    shift = 0.0
                zz[j] = zz[j] + shift * inv_sd
    r_y = np.empty(n)
    r_z = np.empty(n)
    dx = np.empty(n)
    mt0, inv_dt, top = m_t - t0, 1.0 / dt, n_t - 1.0
    has_app = len(approach) > 0
    bvx = bvy = bvz = avx = half_vx = 0.0
    if has_app:
        bvx, bvy, bvz = approach[0], approach[1], approach[2]
        avx = abs(bvx)
        half_vx = 0.5 * avx
    dx_min = np.inf
    for j in range(n):
        pos = zz[j] * sd_t + mt0 - st[j]
        pos *= inv_dt
        pos = min(max(pos, 0.0), top)
        i = int(pos)
        pos -= i
        pos *= dt
        i += pp[j] * n_t
        vx, vy, vz = planes[3, i], planes[4, i], planes[5, i]
        ddx = vx * pos
        ddx += planes[0, i] - plane_x
        ry = vy * pos
        ry += planes[1, i]
        ry -= m_y + ky_sd * zz[j]
        rz = vz * pos
        rz += planes[2, i]
        rz -= m_z + kz_sd * zz[j]
        if has_app:
            s = vx + avx
            s = max(s, half_vx)
            s = max(ddx, 0.0) / s
            ry -= (vy - bvy) * s
            rz -= (vz - bvz) * s
        r_y[j], r_z[j], dx[j] = ry, rz, ddx
        dx_min = min(dx_min, ddx)
    has_rho = not dx_min >= -h
    rho = np.empty(n if has_rho else 0)
    contact = share
    d2 = np.empty(n)
    base = np.empty(n)
    sel = np.empty(n, dtype=np.intp)
    n_sel = 0
    radius = r_shield + r_b
    inner = max(radius - reach, 0.0)
    inner *= inner
    outer_b = (radius + reach) * (radius + reach)
    for j in range(n):
        if has_rho:
            behind = -dx[j] - h
            behind = min(max(behind, 0.0), r_b)
            rj = np.sqrt(r_b * r_b - behind * behind)
            rj += r_shield
            rho[j] = rj
            if not dx[j] >= -(h + r_b):
                contact[j] = 0.0 * share[j]
            inner = max(rj - reach, 0.0)
            inner *= inner
            outer_b = rj + reach
            outer_b *= outer_b
        dd = r_y[j] * r_y[j]
        dd += r_z[j] * r_z[j]
        d2[j] = dd
        base[j] = 1.0 if dd <= inner else 0.0
        if dd > inner and dd < outer_b:
            sel[n_sel] = j
            n_sel += 1
    return d2, base, contact, rho, sel[:n_sel], has_rho, r_y, r_z


@numba.njit(cache=True, nogil=True)
def _lookup(
    r_y, r_z, d2, rho, sel, every, has_rho, sig_a, e0, e1, eta, value, slope,
    r_shield, r_ball, levels, n_col, xi_max, xi_step,
):  # fmt: skip
    """path_pairs._lookup before its sum over eta: the disk probability at every eta node of
    the pairs ``sel`` (or all with ``every``), shape (pairs, E)."""
    n = len(d2) if every else len(sel)
    n_e = len(eta)
    f = np.empty((n, n_e))
    scale = 1.0 / (sig_a * xi_step)
    zero = xi_max / xi_step
    offset = zero - (r_shield + r_ball) * scale
    single = n_e == 1 and eta[0] == 0.0
    m2 = -2.0 * eta
    eta2 = eta * eta
    hi = n_col - 1.0 - 1e-9
    lev_scale = (levels - 1) / r_ball
    lev, li, proj = 0.0, 0, 0.0
    for a in range(n):
        j = a if every else sel[a]
        if has_rho:
            offset = zero - rho[j] * scale
            lev = (rho[j] - r_shield) * lev_scale
            li = min(int(lev), levels - 2)
            lev -= li
        if not single:
            proj = r_y[j] * e0
            proj += r_z[j] * e1
        for e in range(n_e):
            if single:
                d = np.sqrt(d2[j])
            else:
                d = proj * m2[e]
                d += eta2[e]
                d += d2[j]
                d = np.sqrt(max(d, 0.0))
            d *= scale
            d += offset
            d = min(max(d, 0.0), hi)
            c = np.floor(d)
            d -= c
            ci = int(c)
            if has_rho:
                ci += li * (n_col - 1)
            f0 = slope[ci] * d
            f0 += value[ci]
            if has_rho:
                ci += n_col - 1
                f1 = slope[ci] * d
                f1 += value[ci]
                f1 -= f0
                f1 *= lev
                f0 += f1
            f[a, e] = f0
    return f


def warm_up() -> None:
    """Compile the kernels (or load them from the disk cache) now, not in a decision: one
    tiny case through :func:`pair_values` and the packing, with the types every call uses."""
    from thinkfast.decide.path_pairs import conditional
    from thinkfast.decide.shield_paths import shield_paths

    geom = BlockGeometry(0.0, 0.2, 0.005, 0.03)
    centre = np.zeros((1, 3, 3))
    centre[0, :, 0] = (-0.1, 0.0, 0.1)  # through the touch depth: contact radii and a cut
    paths = shield_paths(np.arange(3) * 0.1, centre, geom)
    b = conditional(np.array([0.2, 0.0, 0.1]), np.diag([0.01, 0.02, 0.001]), 1e-4)
    eta, w = np.array([-0.01, 0.0, 0.01]), np.full(3, 1.0 / 3.0)
    one, zero = np.zeros(1, dtype=np.intp), np.zeros(1)
    pair_values(paths, one, zero, zero, True, b, geom, np.array([-5.0, 0.0, 0.0]), None, eta,
                w, 5)  # fmt: skip
    pair_values(paths, one, zero, zero, False, b, geom, None, np.full(1, 0.01), eta, w, 5)
    shield_jit.warm_up()  # the shield centres' row pass
    traj_jit.warm_up()  # the joint paths
