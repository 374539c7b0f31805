"""Sampled shield-centre paths, packed for the path-value kernel (:mod:`path_value`).

A path is the shield centre in ``base`` on a uniform time grid; between samples it is linear,
before the first sample it is at the first, after the last it is held there. Packing computes
once what every belief update needs: each segment's velocity, bounding boxes and speeds (for
pruning and for choosing quadrature nodes) and the times at which the path crosses the *touch
depth* ``plane_x - h - r_b`` (behind it, the ball's centre stops at the plane before it can
touch the disk: the value jumps there, and the kernel integrates finely around such times).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.robot import kernels

MAX_CUTS = 4  # touch-depth crossings kept per path; a path with more is always integrated finely


class BlockGeometry(NamedTuple):
    """Plane and the bodies that meet on it, all in metres."""

    plane_x: float
    shield_radius: float
    half_thickness: float
    ball_radius: float

    @property
    def touch_x(self) -> float:
        """x below which a shield centre cannot touch a ball whose centre stops at the plane."""
        return self.plane_x - self.half_thickness - self.ball_radius


def block_geometry(robot, plane_x: float, ball_radius: float) -> BlockGeometry:
    """The geometry of ``robot``'s shield (URDF cylinder) for a plane ``x = plane_x`` [m]."""
    return BlockGeometry(
        float(plane_x), robot.shield_radius, 0.5 * robot.shield_thickness, float(ball_radius)
    )


class ShieldPaths(NamedTuple):
    """M shield-centre paths on one uniform time grid (build with :func:`shield_paths`).

    Attributes:
        t0: time of sample 0 [s] (on the paths' own clock).
        dt: sample spacing [s].
        planes: per sample, the centre (x, y, z) [m] and the velocity of the segment that
            starts there [m/s] (zero at the last sample: held), one plane per component, shape
            (6, M * T), motion-major (planes keep the kernel's gathers contiguous).
        n_samples: T.
        speed: largest lateral (y, z) speed of each path [m/s], shape (M,).
        box: lateral bounding box of each path, rows y_min, z_min, y_max, z_max [m], shape
            (4, M).
        front: how far each path gets in front of the plane, max(x - plane_x, 0) [m], (M,).
        x_range: smallest and largest x of each path [m], shape (M, 2).
        x_speed: largest |dx/dt| of each path [m/s], shape (M,).
        cuts: times [s, path clock] at which x crosses the touch depth, ascending, padded with
            inf, shape (M, MAX_CUTS); a path with more crossings has ``-inf`` first.
        cut_yz: the shield's (y, z) [m] at those times (nan where padded), (M, MAX_CUTS, 2).
        cut_in: whether each crossing enters the touch range (x rising through the touch
            depth: contact possible after it) rather than leaves it, (M, MAX_CUTS) bool.
    """

    t0: float
    dt: float
    planes: np.ndarray
    n_samples: int
    speed: np.ndarray
    box: np.ndarray
    front: np.ndarray
    x_range: np.ndarray
    x_speed: np.ndarray
    cuts: np.ndarray
    cut_yz: np.ndarray
    cut_in: np.ndarray

    @property
    def n_paths(self) -> int:
        return len(self.speed)


def shield_paths(times: np.ndarray, centre: np.ndarray, geom: BlockGeometry) -> ShieldPaths:
    """Pack sampled shield centres for :func:`thinkfast.decide.path_value.block_probability`.

    Args:
        times: sample times [s], shape (T,), uniformly spaced (T = 1: a shield at rest).
        centre: shield centres in ``base`` [m], shape (M, T, 3) (or (T, 3) for one path).
        geom: the plane and the bodies (for the touch depth).

    Raises:
        ValueError: shapes disagree, the grid is not uniform and increasing, or values are not
            finite.
    """
    times = np.asarray(times, dtype=float)
    c = np.asarray(centre, dtype=float)
    if c.ndim == 2:
        c = c[None]
    if times.ndim != 1 or c.ndim != 3 or c.shape[1:] != (len(times), 3) or len(times) == 0:
        raise ValueError(f"need times (T,) and centre (M, T, 3), got {times.shape}, {c.shape}")
    if not (np.isfinite(times).all() and np.isfinite(c).all()):
        raise ValueError("times and centres must be finite")
    dt = float(times[1] - times[0]) if len(times) > 1 else 1.0
    # np.allclose(np.diff(times), dt, rtol=1e-6, atol=1e-12), without its overhead
    if len(times) > 1 and not (
        dt > 0.0 and (np.abs((times[1:] - times[:-1]) - dt) <= 1e-12 + 1e-6 * abs(dt)).all()
    ):
        raise ValueError("times must be uniformly spaced and increasing")
    m, t = c.shape[:2]
    planes = np.empty((6, m * t))
    planes[:3] = c.reshape(m * t, 3).T
    return pack(times, planes, geom)


def pack(times: np.ndarray, planes: np.ndarray, geom: BlockGeometry) -> ShieldPaths:
    """:func:`shield_paths` of centres already in ``planes[:3]`` (the layout of
    :attr:`ShieldPaths.planes`), unchecked: ``times`` (T,) uniform and increasing, ``planes``
    (6, M * T) finite, float64 and C-contiguous. Fills the velocity rows ``planes[3:]`` in
    place. Compiled (:mod:`pack_jit`) when the kernels are (:mod:`thinkfast.robot.kernels`):
    :func:`pack_numpy`'s values bit for bit."""
    if not kernels.compiled():
        return pack_numpy(times, planes, geom)
    from thinkfast.decide.pack_jit import pack_kernel

    times = np.asarray(times, dtype=float)
    n_t = len(times)
    dt = float(times[1] - times[0]) if n_t > 1 else 1.0
    return ShieldPaths(
        float(times[0]),
        dt,
        planes,
        n_t,
        *pack_kernel(times, planes, n_t, geom.plane_x, geom.touch_x, MAX_CUTS),
    )


def pack_numpy(times: np.ndarray, planes: np.ndarray, geom: BlockGeometry) -> ShieldPaths:
    """:func:`pack` in numpy (the reference of the compiled kernel)."""
    n_t = len(times)
    m = planes.shape[1] // n_t
    dt = float(times[1] - times[0]) if n_t > 1 else 1.0
    pos = planes[:3].reshape(3, m, n_t)
    vel = planes[3:].reshape(3, m, n_t)
    np.subtract(pos[:, :, 1:], pos[:, :, :-1], out=vel[:, :, :-1])
    vel[:, :, :-1] *= 1.0 / dt
    vel[:, :, -1] = 0.0
    lateral = vel[1] * vel[1]
    lateral += vel[2] * vel[2]
    lo, hi = np.minimum.reduce(pos, axis=2), np.maximum.reduce(pos, axis=2)  # (3, M)
    x_range = np.array((lo[0], hi[0])).T  # (M, 2), rows of the (2, M) array
    return ShieldPaths(
        float(times[0]),
        dt,
        planes,
        n_t,
        np.sqrt(np.maximum.reduce(lateral, axis=1)),
        np.concatenate([lo[1:], hi[1:]]),
        np.maximum(hi[0] - geom.plane_x, 0.0),
        x_range,
        np.maximum.reduce(np.abs(vel[0]), axis=1),
        *_cuts(times, pos, geom.touch_x),
    )


def _cuts(times: np.ndarray, pos: np.ndarray, touch_x: float) -> tuple[np.ndarray, ...]:
    """Times (M, MAX_CUTS) at which the paths ``pos`` (3, M, T) cross ``x = touch_x`` (linear
    between samples), the (y, z) there (M, MAX_CUTS, 2) and whether x rises (M, MAX_CUTS)."""
    m = pos.shape[1]
    times_out = np.full((m, MAX_CUTS), np.inf)
    yz_out = np.full((m, MAX_CUTS, 2), np.nan)
    in_out = np.zeros((m, MAX_CUTS), dtype=bool)
    depth = pos[0] - touch_x
    above = depth >= 0.0
    m_idx, i_idx = np.nonzero(above[:, 1:] != above[:, :-1])
    if m_idx.size == 0:
        return times_out, yz_out, in_out
    d0, d1 = depth[m_idx, i_idx], depth[m_idx, i_idx + 1]
    u = d0 / (d0 - d1)
    rank = np.arange(len(m_idx)) - np.searchsorted(m_idx, m_idx)  # within its path
    keep = rank < MAX_CUTS
    mk, rk, ik, uk = m_idx[keep], rank[keep], i_idx[keep], u[keep]
    times_out[mk, rk] = times[ik] + (times[ik + 1] - times[ik]) * uk
    yz0, yz1 = pos[1:, mk, ik], pos[1:, mk, ik + 1]  # (2, K)
    yz_out[mk, rk] = (yz0 + (yz1 - yz0) * uk).T
    in_out[mk, rk] = above[mk, ik + 1]
    if len(mk) < len(m_idx):  # paths with more crossings than kept
        times_out[m_idx[~keep], 0] = -np.inf
    return times_out, yz_out, in_out
