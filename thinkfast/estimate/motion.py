"""Ball motion model of the filter: constant velocity, gravity as a known input, optional drag.

State ``[X Y Z Vx Vy Vz]`` in ``base`` [m, m/s], z up. Acceleration ``a = (0, 0, -g) - k |v| v``
(quadratic drag with coefficient k [1/m]; ``k = 0`` is the paper's model). Process noise is
white acceleration of spectral density ``q`` [m^2/s^3] per axis.
"""

from __future__ import annotations

import math

import numpy as np


def accel(vel: np.ndarray, gravity: float, drag: float) -> np.ndarray:
    """Model acceleration [m/s^2] at velocity ``vel`` [m/s], shape (3,)."""
    a = np.array([0.0, 0.0, -gravity])
    if drag > 0.0:
        a -= drag * math.sqrt(float(vel @ vel)) * vel
    return a


def transition(
    mean: np.ndarray, dt: float, gravity: float, drag: float
) -> tuple[np.ndarray, np.ndarray]:
    """Propagate the mean by ``dt`` [s]; returns (new mean (6,), state Jacobian F (6, 6)).

    Without drag the motion is exact. With drag the mean takes one classical Runge-Kutta step
    and F is the series ``I + A dt + (A dt)^2 / 2`` of the dynamics' Jacobian
    ``A = [[0, I], [0, -k (|v| I + v v^T / |v|)]]`` at the mid-step velocity.
    """
    f = np.eye(6)
    f[0, 3] = f[1, 4] = f[2, 5] = dt
    if drag == 0.0:
        new = f @ mean
        new[2] -= 0.5 * gravity * dt * dt
        new[5] -= gravity * dt
        return new, f

    def deriv(x: np.ndarray) -> np.ndarray:
        return np.concatenate([x[3:], accel(x[3:], gravity, drag)])

    k1 = deriv(mean)
    k2 = deriv(mean + 0.5 * dt * k1)
    k3 = deriv(mean + 0.5 * dt * k2)
    k4 = deriv(mean + dt * k3)
    new = mean + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    v = 0.5 * (mean[3:] + new[3:])
    speed = math.sqrt(float(v @ v))
    a = np.zeros((6, 6))
    a[0, 3] = a[1, 4] = a[2, 5] = 1.0
    if speed > 0.0:
        a[3:, 3:] = -drag * (speed * np.eye(3) + np.outer(v, v) / speed)
    ad = a * dt
    return new, np.eye(6) + ad + 0.5 * (ad @ ad)


_Q_INDEX = np.array([0, 7, 14, 21, 28, 35, 3, 10, 17, 18, 25, 32])  # flat (6, 6) positions


def process_noise(dt: float, accel_psd) -> np.ndarray:
    """Discrete process noise Q(dt) of white acceleration, shape (6, 6).

    Per axis with spectral density q: ``[[q dt^3 / 3, q dt^2 / 2], [q dt^2 / 2, q dt]]``.
    """
    q = np.asarray(accel_psd, dtype=float)
    b = q * (0.5 * dt * dt)
    out = np.zeros(36)
    out[_Q_INDEX] = np.concatenate([q * (dt**3 / 3.0), q * dt, b, b])
    return out.reshape(6, 6)


def two_point(
    p0: np.ndarray, p1: np.ndarray, dt: float, r0: np.ndarray, gravity: float, drag: float
) -> tuple[np.ndarray, np.ndarray]:
    """Initial state from two positions ``dt`` [s] apart (p1 is the later one).

    The finite difference ``(p1 - p0) / dt`` is the mid-interval velocity; half a step of the
    model acceleration brings it to the time of p1.

    Args:
        p0, p1: measured positions [m], shape (3,) each.
        dt: time between them [s], > 0.
        r0: measurement noise covariance [m^2], shape (3, 3).

    Returns:
        (mean (6,), covariance (6, 6)) of the state at p1's time, the covariance propagated
        from r0: ``[[R, R / dt], [R / dt, 2 R / dt^2]]``.
    """
    v_mid = (p1 - p0) / dt
    mean = np.concatenate([p1, v_mid + 0.5 * dt * accel(v_mid, gravity, drag)])
    cov = np.empty((6, 6))
    cov[:3, :3] = r0
    cov[:3, 3:] = cov[3:, :3] = r0 / dt
    cov[3:, 3:] = 2.0 * r0 / (dt * dt)
    return mean, cov
