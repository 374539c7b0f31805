"""Terminal values: P(ball crosses within the shield radius of goal g AND after the shield arrives).

For every terminal edge e = (goal g, remaining arrival time t_e) the value is

    V_e = P( |(Y, Z) - g| <= r  and  tau > t_e + margin ),   (Y, Z, tau) ~ N(o_bar, Sigma_o),

with the full 3x3 covariance (the Y/Z-tau correlation matters: depth noise moves both). Units:
m, s; values are probabilities.

Everything belief-dependent is done once per goal on a time grid shared by all goals (tau
conditioned on (Y, Z), the disk mass along one axis by Gauss-Legendre, one Toeplitz product for
the time profile); the per-terminal work is one linear interpolation.

The method step by step and its error bounds: docs/DESIGN.md, "Terminal values".
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

from thinkfast.config import spec
from thinkfast.decide.shield_disk import disk_nodes, plane_frame
from thinkfast.errors import ConfigError
from thinkfast.robot import kernels

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
BACKUPS = ("qmdp", "lookahead")  # [value] backup
_BLAS_ONE_THREAD = 250_000  # m n k below OpenBLAS's threading threshold (4 * 65536)


@dataclasses.dataclass(frozen=True)
class ValueConfig:
    """Terminal-value parameters (TOML table)."""

    margin: float = spec(
        0.02,
        doc="latency margin: the shield must be at the goal this long before the ball",
        unit="s",
        lo=0.0,
    )
    min_nodes: int = spec(6, doc="fewest Gauss-Legendre nodes per piece of a disk", lo=2, hi=512)
    max_nodes: int = spec(48, doc="most Gauss-Legendre nodes per piece of a disk", lo=2, hi=512)
    nodes_per_sigma: float = spec(
        2.0, doc="Gauss-Legendre nodes per scale of the integrand along u", lo=0.1, hi=100.0
    )
    cell_sigma: float = spec(
        0.25,
        doc="finest quadrature cell along u when tau follows u closely",
        unit="sigma_u",
        lo=0.01,
        hi=10.0,
    )
    time_points: int = spec(64, doc="points of the shared time grid", lo=8, hi=4096)
    k_sigma: float = spec(
        6.5, doc="integration and pruning range across the plane", unit="sigma", lo=3.0, hi=12.0
    )
    k_time: float = spec(5.0, doc="half-width of the time grid", unit="sigma", lo=3.0, hi=12.0)
    backup: str = spec(
        "qmdp",
        choices=BACKUPS,
        doc="qmdp: every node valued under today's crossing belief (max backup); lookahead: the "
        "children of the node where the arm next chooses valued under the belief it will have "
        "when their edges end, averaged over what the coming detections may show (preposterior, "
        "docs/DESIGN.md)",
    )
    lookahead_min_std: float = spec(
        0.005,
        unit="m",
        lo=0.0,
        doc="the look-ahead runs only when the coming detections move the crossing point's "
        "expected position by at least this std on the plane (else qmdp)",
    )

    def __post_init__(self) -> None:
        if self.max_nodes < self.min_nodes:
            raise ConfigError(
                "ValueConfig", "max_nodes", f"must be >= min_nodes ({self.min_nodes})"
            )


class ValueLayout(NamedTuple):
    """Static data of a tree for :func:`terminal_values` (build once with :func:`layout`).

    Attributes:
        goal_yz: goal positions on the plane (base y, z) [m], shape (G, 2).
        term_goal: goal of each terminal edge, shape (T,).
        radius: shield radius [m].
        flat: ``term_goal * K``, row offsets into the value table, shape (T,).
        toeplitz: ``k - i + K`` for the kernel matrix, shape (K + 1, K).
        cfg: the :class:`ValueConfig`.
    """

    goal_yz: np.ndarray
    term_goal: np.ndarray
    radius: float
    flat: np.ndarray
    toeplitz: np.ndarray
    cfg: ValueConfig


class TerminalValues(NamedTuple):
    """Result of :func:`terminal_values`.

    Attributes:
        value: probability of a block for each terminal edge, shape (T,).
        goal_mass: probability that the crossing lies in each goal's disk, shape (G,).
    """

    value: np.ndarray
    goal_mass: np.ndarray


def layout(
    goal_yz: np.ndarray, term_goal: np.ndarray, radius: float, cfg: ValueConfig
) -> ValueLayout:
    """Precompute what does not depend on the belief.

    Args:
        goal_yz: goal positions (base y, z) [m], shape (G, 2).
        term_goal: goal index of each terminal edge, shape (T,).
        radius: shield radius [m], > 0.
        cfg: value configuration.

    Raises:
        ConfigError: the radius is not positive.
    """
    if not radius > 0.0:
        raise ConfigError("shield", "radius", f"must be > 0, got {radius}")
    k = cfg.time_points
    term_goal = np.asarray(term_goal, dtype=np.intp)
    return ValueLayout(
        goal_yz=np.asarray(goal_yz, dtype=float),
        term_goal=term_goal,
        radius=float(radius),
        flat=term_goal * k,
        toeplitz=np.arange(k)[None, :] - np.arange(k + 1)[:, None] + k,
        cfg=cfg,
    )


def terminal_values(
    lay: ValueLayout, o_mean: np.ndarray, o_cov: np.ndarray, term_remaining: np.ndarray
) -> TerminalValues:
    """Value of every terminal edge under the crossing belief N(o_mean, o_cov).

    Args:
        lay: static layout from :func:`layout`.
        o_mean: (Y_plane [m], Z_plane [m], tau [s]), shape (3,).
        o_cov: its covariance, shape (3, 3).
        term_remaining: time from the belief's time until the shield would be at each terminal's
            goal [s], shape (T,) (the caller aligns the clocks). ``cfg.margin`` is added.

    Returns:
        :class:`TerminalValues` with the (T,) values and the (G,) goal disk masses.
    """
    table, mass, t0, step = value_table(lay, o_mean, o_cov)
    return TerminalValues(table_lookup(lay, table, t0, step, term_remaining), mass)


def terminal_values_numpy(
    lay: ValueLayout, o_mean: np.ndarray, o_cov: np.ndarray, term_remaining: np.ndarray
) -> TerminalValues:
    """:func:`terminal_values` in numpy (the reference of the compiled lookup)."""
    table, mass, t0, step = value_table(lay, o_mean, o_cov)
    return TerminalValues(_lookup_numpy(lay, table, t0, step, term_remaining), mass)


def table_lookup(
    lay: ValueLayout, table: np.ndarray, t0: float, step: float, term_remaining: np.ndarray
) -> np.ndarray:
    """Terminal values (T,) read from a :func:`value_table` ``(table, _, t0, step)`` whose
    rows are ``lay``'s goals (``table`` may be rows of a larger table: a view of (2, G, K));
    compiled (one pass over the edges, tree_jit) or in numpy as the kernels say."""
    if not kernels.compiled():
        return _lookup_numpy(lay, table, t0, step, term_remaining)
    from thinkfast.decide.tree_jit import terminal_lookup

    return terminal_lookup(
        np.ascontiguousarray(term_remaining, dtype=float),
        lay.cfg.margin - t0,
        1.0 / step,
        lay.cfg.time_points - 1.0 - 1e-9,
        lay.flat,
        table[0].reshape(-1),
        table[1].reshape(-1),
    )


def _lookup_numpy(
    lay: ValueLayout, table: np.ndarray, t0: float, step: float, term_remaining: np.ndarray
) -> np.ndarray:
    """:func:`table_lookup` in numpy: linear interpolation of F_g at ``remaining + margin``."""
    pos = np.asarray(term_remaining, dtype=float) + (lay.cfg.margin - t0)
    pos *= 1.0 / step
    np.clip(pos, 0.0, lay.cfg.time_points - 1.0 - 1e-9, out=pos)
    i = pos.astype(np.intp)
    pos -= i
    i += lay.flat
    value = table[1].reshape(-1).take(i)
    value *= pos
    value += table[0].reshape(-1).take(i)
    return value


def value_table(
    lay: ValueLayout, o_mean: np.ndarray, o_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """F_g(t) = P(disk_g, tau > t) on the shared time grid.

    Returns:
        ``(table, goal_mass, t0, step)``: ``table[0]`` is F, shape (G, K), ``table[1]`` its
        forward difference along the grid; the grid is ``t0 + step * arange(K)`` [s];
        goal_mass, shape (G,).
    """
    cfg = lay.cfg
    n_goal, k_pts = len(lay.goal_yz), cfg.time_points
    table = np.zeros((2, n_goal, k_pts))
    mass = np.zeros(n_goal)
    frame = plane_frame(o_mean, o_cov)
    nodes = disk_nodes(frame, lay.goal_yz, lay.radius, cfg)
    if nodes is None:
        return table, mass, float(o_mean[2]), 1.0
    n_alive = len(nodes.goals)
    alive_mass = np.bincount(nodes.row, nodes.mass.sum(axis=1), minlength=n_alive)
    mass[nodes.goals] = alive_mass
    s0, s1 = nodes.tau_lo, nodes.tau_hi  # relative to m_tau
    total = float(alive_mass.sum())
    spread = float(np.sum(nodes.mass * np.square(s1 - s0))) / (12.0 * max(total, 1e-300))
    s_c = math.sqrt(max(frame.s_c2 - spread, 1e-14))
    # Outside m_tau +- k_time sigma_tau every F_g is flat (P_g below, 0 above) within Q(k_time).
    s_t = cfg.k_time * math.sqrt(max(o_cov[2, 2], 1e-14))
    lo_t = max(float(s0.min()) - cfg.k_time * s_c, -s_t)
    hi_t = min(float(s1.max()) + cfg.k_time * s_c, s_t)
    step = max(hi_t - lo_t, 1e-9) / (k_pts - 3)
    t0 = lo_t - step

    inv = 1.0 / step
    d2 = _ramp_deposits(nodes.row, nodes.mass, (s0 - t0) * inv, (s1 - t0) * inv, n_alive, k_pts)
    f = _matmul_single_thread(d2, _ramp_kernel(k_pts, s_c * inv)[lay.toeplitz])
    np.subtract(alive_mass[:, None], f, out=f)
    np.maximum(f, 0.0, out=f)
    np.minimum(f, alive_mass[:, None], out=f)
    table[0, nodes.goals] = f
    table[1, nodes.goals, :-1] = f[:, 1:] - f[:, :-1]
    return table, mass, float(o_mean[2]) + t0, step


def _ramp_deposits(row, mass, p0, p1, n_rows: int, k_pts: int) -> np.ndarray:
    """Second differences of the cumulative segment mass on the grid, shape (A, K + 1).

    The cumulative mass is ``cumsum(cumsum(d2))``. A segment [p0, p1] (grid units) of mass m is
    ``m / L * (ramp(p0) - ramp(p1))`` with ``L = p1 - p0`` (at least 1e-3 steps: a shorter one
    is widened, which moves its mass by less than 1e-3 steps), and a ramp ``(k - p)_+`` has as
    second differences the linear (cloud-in-cell) deposit of a unit at ``p + 1``. Samples of a
    ramp at the grid points are exact, so this is exact for any length.
    """
    top = k_pts - 2.0 - 1e-9
    length = np.maximum(p1 - p0, 1e-3)
    c = mass / length
    pos = np.empty((2,) + p0.shape)
    np.clip(p0, 0.0, top, out=pos[0])
    np.minimum(pos[0] + length, top, out=pos[1])
    pos += 1.0
    j = pos.astype(np.intp)
    frac = pos - j
    j += (row * (k_pts + 1))[:, None]
    wts = np.empty((2,) + pos.shape)
    np.multiply(frac, c, out=wts[1])
    wts[1, 1] *= -1.0  # the ramp at p1 is subtracted
    np.subtract(c, wts[1, 0], out=wts[0, 0])
    np.negative(c, out=wts[0, 1])
    wts[0, 1] -= wts[1, 1]
    idx = np.concatenate([j, j + 1], axis=None)
    return np.bincount(idx, wts.ravel(), minlength=n_rows * (k_pts + 1)).reshape(n_rows, k_pts + 1)


def _matmul_single_thread(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` in row blocks small enough that OpenBLAS keeps each on the calling thread.

    OpenBLAS hands a product to its thread pool above m n k = 262144; on a busy 2-core machine
    waking the pool costs milliseconds now and then, far more than the product itself.
    """
    rows = max(1, _BLAS_ONE_THREAD // (a.shape[1] * b.shape[1]))
    if len(a) <= rows:
        return a @ b
    out = np.empty((len(a), b.shape[1]))
    for i in range(0, len(a), rows):
        np.matmul(a[i : i + rows], b, out=out[i : i + rows])
    return out


def _ramp_kernel(k_pts: int, sigma: float) -> np.ndarray:
    """rho(d) = E[(d + 1 - e)_+], e ~ N(0, sigma^2), for d = -K .. K - 1 (grid steps).

    The double cumulative sum of a unit second difference at i, seen at grid point k, is the ramp
    ``(k - i + 1)_+``; smoothing it with the time noise gives rho(k - i).
    """
    x = np.arange(-k_pts, k_pts) + 1.0
    s = max(sigma, 1e-12)
    z = x / s
    return x * ndtr(z) + s * _INV_SQRT_2PI * np.exp(-0.5 * z * z)
