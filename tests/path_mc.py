"""Monte Carlo references for thinkfast.decide.path_value (test helper).

``model_block``: the kernel's geometric model sampled directly (exact meeting time by fixed-point
iteration on the interpolated path, no quadrature, no tables). ``judge_block``: the simulator's
judge geometry (sphere against the shield cylinder, sampled every 0.5 ms along a straight flight
through the plane) for a smaller sample.
"""

from __future__ import annotations

import numpy as np

from thinkfast.sim.judge import sphere_disk_gap


def shield_at(times: np.ndarray, centre: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Centre (N, 3) of one path (times (T,), centre (T, 3)) at times ``t`` (N,), clamped."""
    return np.stack([np.interp(t, times, centre[:, j]) for j in range(3)], axis=1)


def model_block(times, centre, mean, cov, geom, approach, t_start, n, rng) -> float:
    """P(block) of one path under the module's geometric model, from ``n`` samples."""
    plane_x, r_shield, h, r_b = geom
    s = rng.multivariate_normal(mean, cov, size=n)
    tau = s[:, 2]
    t_meet = tau.copy()
    if approach is not None:
        vx = abs(approach[0])
        for _ in range(8):  # x_ball(t) = plane_x + |vx| (tau - t) meets c_x(t): x alone
            c_x = np.interp(t_meet - t_start, times, centre[:, 0])
            t_meet = tau - np.maximum(c_x - plane_x, 0.0) / vx
    c = shield_at(times, centre, t_meet - t_start)
    yz = s[:, :2]
    if approach is not None:
        yz = yz + np.outer(t_meet - tau, approach[1:])
    a = plane_x - c[:, 0]
    behind = np.clip(a - h, 0.0, r_b)
    rho = r_shield + np.sqrt(r_b * r_b - behind * behind)
    hit = (np.hypot(yz[:, 0] - c[:, 1], yz[:, 1] - c[:, 2]) <= rho) & (a <= h + r_b)
    return float(np.mean(hit))


def judge_block(times, centre, mean, cov, geom, approach, t_start, n, rng, step=5e-4) -> float:
    """P(block) by the judge's sphere-cylinder test along straight flights, ``n`` samples.

    Each sample flies at ``approach`` through the plane at (Y, Z) at tau; contact is checked every
    ``step`` from 0.1 s before tau to tau (the judge stops at the crossing).
    """
    plane_x, r_shield, h, r_b = geom
    s = rng.multivariate_normal(mean, cov, size=n)
    v = np.asarray(approach, dtype=float)
    blocked = np.zeros(n, dtype=bool)
    normal = np.broadcast_to([1.0, 0.0, 0.0], (n, 3))
    for back in np.arange(0.0, 0.1 + 1e-12, step):
        t = s[:, 2] - back
        p = np.column_stack([np.full(n, plane_x), s[:, 0], s[:, 1]]) - back * v
        c = shield_at(times, centre, t - t_start)
        blocked |= sphere_disk_gap(p, c, normal, r_shield, h, r_b) <= 0.0
    return float(np.mean(blocked))


def belief(mean, sig_a, ratio, angle, sd_t, k) -> tuple[np.ndarray, np.ndarray]:
    """A crossing Gaussian built from its conditional structure (thinkfast.decide.path_value):

    (Y, Z) | tau has standard deviations sig_a and ratio * sig_a (major axis at ``angle``) and
    mean slope ``k`` (2,) [m/s] in tau; tau has ``sd_t``. Returns (mean (3,), cov (3, 3)).
    """
    e = np.array([np.cos(angle), np.sin(angle)])
    s_c = sig_a**2 * np.eye(2) + (ratio**2 - 1.0) * sig_a**2 * np.outer(e, e)
    k = np.asarray(k, dtype=float)
    cov = np.empty((3, 3))
    cov[:2, :2] = s_c + sd_t**2 * np.outer(k, k)
    cov[:2, 2] = cov[2, :2] = sd_t**2 * k
    cov[2, 2] = sd_t**2
    return np.asarray(mean, dtype=float), cov


def smoothstep(u: np.ndarray) -> np.ndarray:
    """0 before 0, 1 after 1, C2 in between (a stand-in for a jerk-limited move)."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
