"""Preposterior values: what the detections still to come will tell before the arm commits.

The at-rest backup (:mod:`backup`) values every node under today's crossing belief N(m, S) and
takes the max: an edge that keeps several goals reachable is worth no more than its best
committed continuation, and waiting for the next detections is worth nothing. The one-step
look-ahead here values each child c of the node where the arm next chooses under the belief the
filter will have when c's edge ends (the arm must pick c's continuation then): the detections
captured by then narrow the crossing covariance to S_c, deterministically (the Kalman covariance
recursion with the camera's rate and stereo noise), and the crossing mean then is distributed
N(m, S - S_c). So ``V(c) = E_k[max-backup of c's subtree under N(m + d_k, S_c)]`` over a
degree-3 cubature of that spread on the plane (5 points: the mean and +-sqrt(3) std along its
principal axes, tau following by regression); a committed edge keeps today's value (the
expectation of a fixed action's probability is today's). Pure kernels.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from thinkfast.decide import backup as bk
from thinkfast.decide import values as vl
from thinkfast.estimate import crossing as delta
from thinkfast.estimate.belief import FilterConfig, stereo_r
from thinkfast.estimate.motion import process_noise, transition

_H_ROWS = 3  # the filter measures the position: H = [I 0]


class Foresight(NamedTuple):
    """How the coming detections inform the belief.

    Attributes:
        fcfg: the filter parameters of the camera (stereo noise, process noise, gravity, drag).
        sensor: the camera origin in the belief's frame [m], shape (3,).
        period: time between its frames [s] (1 / fps).
    """

    fcfg: FilterConfig
    sensor: np.ndarray
    period: float


class Ahead(NamedTuple):
    """The crossing belief at the commit time, seen from today (today's clock for tau).

    Attributes:
        cov: crossing covariance then, S_c, shape (3, 3).
        spread: covariance of the crossing mean then, S - S_c (positive semi-definite), (3, 3).
        detections: frames captured before the commit time (the filter's updates by then).
    """

    cov: np.ndarray
    spread: np.ndarray
    detections: int


def detections_by(horizon: float, period: float) -> int:
    """Frames captured within ``horizon`` [s] of the newest one and delivered by then (a frame
    reaches the planner as late after its capture as the newest did)."""
    return max(int(math.floor(horizon / period + 1e-9)), 0)


def future_state_cov(
    mean: np.ndarray, cov: np.ndarray, n: int, model: Foresight, r_extra: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The state after ``n`` more frames: (mean (6,), covariance without them, with them).

    Both covariances are propagated along the predicted mean with the filter's process noise;
    the second also takes ``n`` position updates with the stereo noise at the predicted
    position (plus ``r_extra``, the filter's adapted R, (3, 3)). Deterministic: it needs no
    measurement, only the rate and the noise model.
    """
    f_cfg = model.fcfg
    m = np.asarray(mean, dtype=float)
    prior = np.array(cov, dtype=float)
    post = prior.copy()
    q = process_noise(model.period, f_cfg.accel_psd)
    for _ in range(n):
        m, f = transition(m, model.period, f_cfg.gravity, f_cfg.drag)
        prior = f @ prior @ f.T + q
        post = f @ post @ f.T + q
        r = stereo_r(m[:3], model.sensor, f_cfg)
        if r_extra is not None:
            r = r + r_extra
        s = post[:_H_ROWS, :_H_ROWS] + r
        gain = np.linalg.solve(s, post[:_H_ROWS, :]).T  # P H^T S^-1 (S symmetric)
        post = post - gain @ post[:_H_ROWS, :]
        post = 0.5 * (post + post.T)
    return m, 0.5 * (prior + prior.T), post


def ahead(
    mean: np.ndarray,
    cov: np.ndarray,
    today: np.ndarray,
    horizon: float,
    model: Foresight,
    plane_x: float,
    min_std: float = 0.0,
    r_extra: np.ndarray | None = None,
) -> Ahead | None:
    """The crossing belief ``horizon`` [s] from the newest detection, or None when no frame
    comes before it, the predicted ball no longer crosses the plane, or the coming frames
    move the crossing point's expected position by less than ``min_std`` [m] on the plane
    (the look-ahead would be QMDP).

    Args:
        mean, cov: the ball belief now (6,), (6, 6) [m, m/s].
        today: today's crossing covariance S (3, 3) (the delta method at ``mean``).
        horizon: time to the commit [s]. model: the camera and the filter. plane_x: [m].
        min_std: [m], see above. r_extra: the filter's adapted measurement noise (3, 3), or None.

    The frames' share is taken where the delta method puts the predicted state, without them
    (P) and with them (P_c): whitened by P's Cholesky factor, ``M = Lp^-1 P_c Lp^-T`` has its
    eigenvalues in [0, 1] (an update only removes variance) and carries over to today's
    crossing covariance S = Lt Lt^T as ``S_c = Lt M Lt^T`` and ``spread = Lt (I - M) Lt^T``:
    both positive semi-definite and summing to S (the future means average to today's belief,
    whatever the process noise and the linearisation point add to the prediction).
    """
    n = detections_by(horizon, model.period)
    if n == 0:
        return None
    m, prior, post = future_state_cov(mean, cov, n, model, r_extra)
    g = model.fcfg.gravity
    c_prior = delta.crossing(m, prior, plane_x, g)
    c_post = delta.crossing(m, post, plane_x, g)
    if not (c_prior.ok and c_post.ok):
        return None
    try:  # what the frames leave of the predicted crossing, whitened: M = Lp^-1 S_post Lp^-T
        lp = np.linalg.cholesky(c_prior.cov)
        lt = np.linalg.cholesky(np.asarray(today, dtype=float))
    except np.linalg.LinAlgError:
        return None
    half = np.linalg.solve(lp, c_post.cov)
    left = np.linalg.solve(lp, half.T)
    left = np.clip(0.5 * (left + left.T), -1.0, 1.0)
    lam, vec = np.linalg.eigh(left)
    left = (vec * np.clip(lam, 0.0, 1.0)) @ vec.T  # 0 <= M <= I: an update only removes
    future = lt @ left @ lt.T
    spread = lt @ (np.eye(3) - left) @ lt.T
    spread = 0.5 * (spread + spread.T)
    if lateral_std(spread) < min_std:
        return None
    return Ahead(0.5 * (future + future.T), spread, n)


def lookahead_backup(
    vlay: vl.ValueLayout,
    blay: bk.BackupLayout,
    back: bk.Backup,
    mean: np.ndarray,
    ahead: Ahead,
    remaining: np.ndarray,
    node: int,
) -> bk.Backup:
    """``back`` (today's QMDP backup) with the children of ``node`` worth the cubature mean of
    their max backup under N(mean + d_k, S_k), d_k and S_k from :func:`sigma_points` of
    ``ahead``, and ``node`` the best of those and its own terminal edges (today's).

    Args:
        vlay, blay: the tree's value and backup layouts. mean: today's crossing mean (3,).
        remaining: every terminal edge's time to arrival from the belief's time [s] (T,).
        node: where the arm chooses next (its ancestors keep their QMDP values).
    """
    lo = int(blay.child_start[node])
    hi = lo + int(blay.child_count[node])
    offsets, weights, cov = sigma_points(ahead.spread, ahead.cov)
    acc = np.zeros(hi - lo)
    if len(weights) == 1:  # nothing to learn about the mean: today's layout, one table
        tv = vl.terminal_values(vlay, mean + offsets[0], cov, remaining)
        acc += bk.backup(blay, tv.value, tv.goal_mass).value[lo:hi]
    else:  # every point's goals in one table under N(mean, cov), on the coarser layout
        g = len(vlay.goal_yz)
        shifted = (vlay.goal_yz[None, :, :] - offsets[:, None, :2]).reshape(-1, 2)
        lay = coarse(vlay)._replace(goal_yz=shifted)
        table, mass, t0, step = vl.value_table(lay, mean, cov)
        for k, (d, w) in enumerate(zip(offsets, weights, strict=True)):
            rows = table[:, k * g : (k + 1) * g]
            value = vl.table_lookup(lay, rows, t0 + float(d[2]), step, remaining)
            acc += w * bk.backup(blay, value, mass[k * g : (k + 1) * g]).value[lo:hi]
    value, cv = back.value.copy(), back.child_value.copy()
    value[lo:hi] = acc
    cv[node] = acc.max(initial=0.0)
    value[node] = max(float(back.term_value[node]), float(cv[node]))
    return back._replace(value=value, child_value=cv)


# the look-ahead's value parameters: the sigma points' goals in one table at about a third of
# today's cost per point, values within 0.005 of today's parameters (docs/DESIGN.md)
COARSE = dict(time_points=24, min_nodes=4, max_nodes=16, nodes_per_sigma=1.0, k_sigma=4.5)


_COARSE: dict[int, tuple[vl.ValueLayout, vl.ValueLayout]] = {}  # id -> (layout, coarse)


def coarse(vlay: vl.ValueLayout) -> vl.ValueLayout:
    """``vlay`` on the look-ahead's coarser value parameters (:data:`COARSE`; its margin),
    built once per layout."""
    hit = _COARSE.get(id(vlay))
    if hit is None or hit[0] is not vlay:
        cfg = dataclasses.replace(vlay.cfg, **COARSE)
        hit = (vlay, vl.layout(vlay.goal_yz, vlay.term_goal, vlay.radius, cfg))
        _COARSE[id(vlay)] = hit
    return hit[1]


def sigma_points(
    spread: np.ndarray, future: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The crossing means to come and the covariance around them: (offsets (K, 3), weights
    (K,), covariance (3, 3)).

    On the plane, the degree-3 rule with a centre: the mean, weight 1/3, and +-sqrt(3 lambda_i)
    e_i along the principal axes of the (Y, Z) spread, 1/6 each (each axis has the Gaussian's
    fourth moment); tau moves with them by its regression on (Y, Z), and the rest of its spread
    joins ``future``'s tau variance, so the points' covariance plus the returned one is
    ``spread + future`` still. A zero spread is the mean alone, weight 1, with ``future``.
    """
    lat = 0.5 * (spread[:2, :2] + spread[:2, :2].T)
    lam, vec = np.linalg.eigh(lat)
    live = lam > 1e-300
    beta = np.zeros(2)
    if live.all():
        beta = np.linalg.solve(lat, spread[:2, 2])
    elif live.any():
        i = int(np.argmax(lam))
        beta = vec[:, i] * (float(vec[:, i] @ spread[:2, 2]) / float(lam[i]))
    rest = max(float(spread[2, 2] - beta @ spread[:2, 2]), 0.0)
    cov = np.array(future, dtype=float)
    cov[2, 2] += rest
    points, weights = [np.zeros(3)], [1.0]
    for k in np.flatnonzero(live).tolist():
        d = math.sqrt(3.0 * float(lam[k])) * vec[:, k]
        d3 = np.array([d[0], d[1], float(beta @ d)])
        points += [d3, -d3]
        weights += [1.0 / 6.0, 1.0 / 6.0]
        weights[0] -= 1.0 / 3.0
    return np.array(points), np.array(weights), cov


def lateral_std(spread: np.ndarray) -> float:
    """Largest std [m] of the crossing point's spread on the plane (the (Y, Z) block)."""
    return math.sqrt(max(float(np.linalg.eigvalsh(spread[:2, :2]).max()), 0.0))
