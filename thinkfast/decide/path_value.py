"""P(block) for shields that may still be moving: the crossing belief against sampled shield paths.

Pure computation (no I/O, no clocks). Inputs: M shield-centre paths sampled on one uniform time
grid (:func:`thinkfast.decide.shield_paths.shield_paths`), the crossing Gaussian
``(Y, Z, tau) ~ N(mean, cov)`` of :mod:`thinkfast.estimate.crossing` (tau from the caller's
"now") and the block geometry. Output: for each path, the probability that the ball meets the
shield (:func:`block_probability`). Today's terminal values (:mod:`values`) ask for arrival at
rest before tau; this asks what the judge asks: does the ball meet the disk, moving or not.
Units: m, s.

The value is a lower bound (the judge's sphere against the shield cylinder, as a disk of radius
``rho`` in the plane), integrated by rules for a standard normal along tau and along the
belief's major axis, with the isotropic disk table (:mod:`iso_disk`).

Geometry, approximations, method and accuracy: docs/DESIGN.md, "Path values".
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from thinkfast.config import spec
from thinkfast.decide.normal_rules import cells, normal_rule
from thinkfast.decide.path_pairs import (
    REACH_A,
    REACH_Z,
    CrossingConditional,
    conditional,
    cut_cells,
    disk_mean,
    relative,
)
from thinkfast.decide.shield_paths import BlockGeometry, ShieldPaths
from thinkfast.robot import kernels


@dataclasses.dataclass(frozen=True)
class PathValueConfig:
    """Quadrature parameters of :func:`block_probability` (TOML table)."""

    refine: float = spec(
        1.0, doc="node density factor (2: twice the nodes per scale)", lo=0.25, hi=8.0
    )
    step_ratio: float = spec(
        1.5, doc="trapezoid node spacing per scale of the integrand", lo=0.1, hi=3.0
    )
    k_sigma: float = spec(
        4.5, doc="half-width of the trapezoid rules", unit="sigma", lo=3.0, hi=9.0
    )
    jump_step: float = spec(
        0.5,
        doc="largest tau node spacing when a path crosses the touch depth near tau",
        unit="sigma_tau",
        lo=0.05,
        hi=2.0,
    )
    max_time_nodes: int = spec(97, doc="most nodes along tau", lo=1, hi=2001)
    max_lateral_nodes: int = spec(33, doc="most nodes along the major axis", lo=1, hi=2001)
    radius_levels: int = spec(
        5, doc="radius levels between R and R + r_b (shield behind the plane)", lo=2, hi=64
    )
    sigma_floor: float = spec(
        1e-4, doc="smallest lateral standard deviation", unit="m", lo=1e-7, lo_open=True
    )


def block_probability(
    paths: ShieldPaths,
    o_mean: np.ndarray,
    o_cov: np.ndarray,
    geom: BlockGeometry,
    approach: np.ndarray | None = None,
    t_start: float | np.ndarray = 0.0,
    cfg: PathValueConfig = PathValueConfig(),
    index: np.ndarray | None = None,
) -> np.ndarray:
    """P(the ball meets each shield path), shape (M,) (or (N,) with ``index``).

    Args:
        paths: from :func:`thinkfast.decide.shield_paths.shield_paths` (same ``geom``).
        o_mean: crossing mean (Y [m], Z [m], tau [s]), tau from "now", shape (3,).
        o_cov: its covariance, shape (3, 3).
        geom: plane, shield and ball.
        approach: mean ball velocity at the crossing [m/s], shape (3,), vx < 0; None: the ball
            is taken to meet an off-plane shield at the plane.
        t_start: when each path's clock reads ``0`` [s, from "now"], scalar or shape (M,) (or
            (N,) with ``index``): the shield at time ``tau`` is the path at ``tau - t_start``.
        cfg: quadrature parameters.
        index: score only these paths, shape (N,) (e.g. this update's candidates among all the
            packed edges); default all.
    """
    b = conditional(o_mean, o_cov, cfg.sigma_floor)
    cand = None if index is None else np.asarray(index, dtype=np.intp)  # None: all paths
    n_paths = paths.n_paths if cand is None else len(cand)
    keep = _reachable(paths, cand, b, geom, approach)  # positions in cand
    if keep.size == 0:
        return np.zeros(n_paths)
    alive = keep if cand is None else cand[keep]
    start = np.asarray(t_start, dtype=float)
    if start.ndim == 0:
        start = np.full(keep.size, float(start))
    else:
        start = np.broadcast_to(start, (n_paths,))[keep]
    ze, we = normal_rule(
        b.sig_a / b.sig_e / cfg.refine if b.sig_e > 0 else math.inf,
        cfg.max_lateral_nodes,
        cfg.step_ratio,
        cfg.k_sigma,
    )
    # (path, tau node) pairs: paths whose value jumps near tau (they cross the touch depth)
    # take the fine rule, each node standing for its cell; the others a smooth rule
    jumps = _jumps(paths, alive, start, b, geom, cfg)
    out = np.zeros(n_paths)
    eta = b.sig_e * ze
    jit = kernels.compiled()  # pair_jit's one pass, else the numpy reference (bit for bit)
    if jit:
        from thinkfast.decide.pair_jit import pair_values
    if not np.logical_or.reduce(jumps):  # pairs as (A, Q); .any() without its wrapper
        zt, wt = normal_rule(
            _time_scale(paths, alive, b, geom) / cfg.refine,
            cfg.max_time_nodes,
            cfg.step_ratio,
            cfg.k_sigma,
        )
        if jit:
            val = pair_values(paths, alive, start, zt, True, b, geom, approach, None, eta, we,
                              cfg.radius_levels)  # fmt: skip
            out[keep] = val.reshape(len(alive), len(zt)) @ wt
        else:
            rel = relative(paths, alive[:, None], start[:, None], b, zt, geom, approach)
            out[keep] = disk_mean(*rel, b, eta, we, geom, cfg.radius_levels) @ wt
        return out
    parts = []  # pairs flat, with the half width of each node's cell [s] (0: the node alone)
    for group in (~jumps, jumps):
        n = int(np.count_nonzero(group))
        if n == 0:
            continue
        jump = group is jumps
        zt, wt = normal_rule(
            _time_scale(paths, alive[group], b, geom) / cfg.refine,
            cfg.max_time_nodes,
            cfg.step_ratio,
            cfg.k_sigma,
            cfg.jump_step / cfg.refine if jump else None,
        )
        half = 0.5 * b.sd_t * cells(zt, wt) if jump else np.zeros(len(zt))
        tiled = [np.concatenate((x,) * n) for x in (zt, wt, half)]  # np.tile, unwrapped
        parts.append((np.repeat(np.flatnonzero(group), len(zt)), *tiled))
    which, z, w, half = (np.concatenate(a) for a in zip(*parts, strict=True))
    path = alive[which]
    if jit:
        w *= pair_values(paths, path, start[which], z, False, b, geom, approach, half, eta, we,
                         cfg.radius_levels)  # fmt: skip
    else:
        z, share = cut_cells(paths, path, start[which], b, z, half)
        r_y, r_z, rho, contact = relative(paths, path, start[which], b, z, geom, approach)
        contact = share if contact is None else contact * share
        w *= disk_mean(r_y, r_z, rho, contact, b, eta, we, geom, cfg.radius_levels)
    out[keep] = np.bincount(which, w, minlength=len(alive))
    return out


def _reachable(
    paths: ShieldPaths, cand, b: CrossingConditional, geom: BlockGeometry, approach
) -> np.ndarray:
    """Positions in ``cand`` (None: all paths) of the paths whose bounding box (widened by the
    meeting shift) comes within reach of a node that weighs: |z| <= 4 along tau and the major
    axis, 4.5 sigma_a across."""
    box = paths.box if cand is None else paths.box[:, cand]
    reach = REACH_A * b.sig_a + geom.shield_radius + geom.ball_radius
    ry = reach + REACH_Z * (abs(b.k[0]) * b.sd_t + abs(b.e[0]) * b.sig_e)
    rz = reach + REACH_Z * (abs(b.k[1]) * b.sd_t + abs(b.e[1]) * b.sig_e)
    my, mz = float(b.m_yz[0]), float(b.m_yz[1])
    if approach is None:
        ok = box[0] < my + ry
        ok &= box[2] > my - ry
        ok &= box[1] < mz + rz
        ok &= box[3] > mz - rz
        return np.flatnonzero(ok)
    v = [float(x) for x in approach]
    speed, front = paths.speed, paths.front
    if cand is not None:
        speed, front = speed[cand], front[cand]
    shift = speed + math.hypot(v[1], v[2])
    shift *= front
    shift *= 1.0 / max(abs(v[0]), 1e-9)
    ok = box[0] - shift < my + ry
    ok &= box[2] + shift > my - ry
    ok &= box[1] - shift < mz + rz
    ok &= box[3] + shift > mz - rz
    return np.flatnonzero(ok)


def _jumps(
    paths: ShieldPaths, alive, start, b: CrossingConditional, geom: BlockGeometry, cfg
) -> np.ndarray:
    """Which paths cross the touch depth (their value jumps) within +-k_sigma of tau and within
    reach of the conditional mean at that time, shape (A,) bool."""
    cuts = paths.cuts[alive]
    dt = cuts + (start - b.m_t)[:, None]  # (A, K) from the mean crossing time [s]
    near = np.abs(dt) < cfg.k_sigma * b.sd_t
    many = cuts[:, 0] == -np.inf
    if not np.logical_or.reduce(near, axis=None):
        return many
    a, k = np.nonzero(near)
    off = paths.cut_yz[alive[a], k] - (b.m_yz + dt[a, k, None] * b.k)  # (N, 2)
    reach = REACH_A * b.sig_a + REACH_Z * b.sig_e + geom.shield_radius + geom.ball_radius
    out = many.copy()
    out[a[np.einsum("nc,nc->n", off, off) < reach * reach]] = True
    return out


def _time_scale(paths: ShieldPaths, group, b: CrossingConditional, geom: BlockGeometry) -> float:
    """Scale of the integrand along tau [sigma_tau] for the paths ``group``: their lateral motion
    against sigma_a, and their x motion inside the touch band against the band's depth."""
    rate = b.sd_t * (float(np.maximum.reduce(paths.speed[group])) + math.hypot(*b.k))
    scale = b.sig_a / rate if rate > 0 else math.inf
    xr = paths.x_range[group]
    band = (xr[:, 0] < geom.plane_x - geom.half_thickness) & (xr[:, 1] > geom.touch_x)
    if np.logical_or.reduce(band):
        x_rate = b.sd_t * float(np.maximum.reduce(paths.x_speed[group][band]))
        if x_rate > 0:
            scale = min(scale, geom.ball_radius / x_rate)
    return scale
