"""Delta method: the ball belief mapped to where and when it crosses the intercept plane.

The ball moves ballistically from the belief mean (constant horizontal velocity, gravity along -z,
no drag) and crosses the plane ``x = d`` of ``base`` after ``tau = (d - X) / Vx``, measured from
the belief's time. The output ``o = h(s) = (Y_plane, Z_plane, tau)``:

    Y_plane = Y + Vy tau,    Z_plane = Z + Vz tau - g tau^2 / 2.

Linearising h at the mean (first-order delta method) gives ``o ~ N(h(mu), J Sigma J^T)`` with the
analytic Jacobian (only the non-zero entries; ``dtau/dX = -1/Vx``, ``dtau/dVx = -tau/Vx``):

    dY/dY = 1, dY/dVy = tau, dY/dX = Vy dtau/dX, dY/dVx = Vy dtau/dVx,
    dZ/dZ = 1, dZ/dVz = tau, dZ/dX = (Vz - g tau) dtau/dX, dZ/dVx = (Vz - g tau) dtau/dVx.

The ball comes from +x, so it approaches the plane only when ``Vx < -min_speed``; otherwise, or
when the crossing is already behind it (``X < d``), the result says so and holds zeros: nothing is
ever divided by a velocity that could be zero.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

REASON_NONE = ""
REASON_RECEDING = "not approaching the plane"
REASON_PAST = "crossing already past"


class Crossing(NamedTuple):
    """Plane-crossing distribution of a ball belief.

    Attributes:
        ok: True when the ball will cross the plane; otherwise the arrays are zeros.
        mean: (Y_plane [m], Z_plane [m], tau [s]) at the mean, shape (3,).
        cov: covariance of the output [m^2, m s, s^2], shape (3, 3).
        jac: Jacobian dh/ds at the mean, shape (3, 6).
        reason: empty when ``ok``, else why there is no crossing.
    """

    ok: bool
    mean: np.ndarray
    cov: np.ndarray
    jac: np.ndarray
    reason: str


def crossing_point(state: np.ndarray, distance: float, gravity: float) -> np.ndarray:
    """h(s) = (Y_plane, Z_plane, tau) for one state [X Y Z Vx Vy Vz] with Vx != 0, shape (3,)."""
    x, y, z, vx, vy, vz = state
    tau = (distance - x) / vx
    return np.array([y + vy * tau, z + vz * tau - 0.5 * gravity * tau * tau, tau])


def crossing(
    mean: np.ndarray,
    cov: np.ndarray,
    distance: float,
    gravity: float,
    min_speed: float = 0.1,
) -> Crossing:
    """Gaussian approximation of the plane crossing of the belief N(mean, cov).

    Args:
        mean: ball state [X Y Z Vx Vy Vz] in base [m, m/s], shape (6,).
        cov: state covariance, shape (6, 6).
        distance: plane position d along base x [m].
        gravity: gravity magnitude g [m/s^2] (acting along -z).
        min_speed: approach speed below which the ball is treated as not approaching [m/s].

    Returns:
        A :class:`Crossing`; ``ok`` is False (and ``reason`` says why) when there is none.
    """
    x, vx, vy, vz = mean[0], mean[3], mean[4], mean[5]
    if not vx < -min_speed:
        return _none(REASON_RECEDING)
    if x < distance:
        return _none(REASON_PAST)
    o = crossing_point(mean, distance, gravity)
    tau = o[2]
    dtau_dx = -1.0 / vx
    dtau_dvx = -tau / vx
    vz_plane = vz - gravity * tau
    jac = np.zeros((3, 6))
    jac[0] = (vy * dtau_dx, 1.0, 0.0, vy * dtau_dvx, tau, 0.0)
    jac[1] = (vz_plane * dtau_dx, 0.0, 1.0, vz_plane * dtau_dvx, 0.0, tau)
    jac[2] = (dtau_dx, 0.0, 0.0, dtau_dvx, 0.0, 0.0)
    out = jac @ cov @ jac.T
    return Crossing(True, o, 0.5 * (out + out.T), jac, REASON_NONE)


def _none(reason: str) -> Crossing:
    return Crossing(False, np.zeros(3), np.zeros((3, 3)), np.zeros((3, 6)), reason)
