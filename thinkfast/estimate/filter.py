"""RIAE-AKF: robust innovation-based adaptive Kalman filter for the ball, in the ``base`` frame.

State ``[X Y Z Vx Vy Vz]`` (m, m/s); measurement: the ball centre ``z = [X Y Z]`` (m), so
``H = [I 0]``. Process model: constant velocity plus gravity as a known input and, optionally,
quadratic air drag; white-acceleration process noise. Time comes in as an argument (``dt``
follows the measurement stamps and may vary).

Each update gates the innovation per axis (an outlier is clipped to the gate and shrunk), adapts
R from a window of recent innovations, and re-initialises an axis that stays an outlier too
long. With ``robust`` and ``adaptive`` both off it is a textbook linear Kalman filter. Late and
out-of-order measurements are rejected and counted, so they never corrupt the state; with
several cameras one up to ``max_lag`` old is fused out of sequence.

The update step by step, its guards and why each is needed, the initialisation and the late
data policy: docs/DESIGN.md, "The filter".
"""

from __future__ import annotations

import functools

import numpy as np

from thinkfast.estimate.belief import (  # noqa: F401  (re-exported: the filter's API)
    _NO3,
    _ONE3,
    _ZERO3,
    _ZERO33,
    STATUS_FIRST,
    STATUS_INIT,
    STATUS_LATE,
    STATUS_PAST,
    STATUS_UPDATED,
    Belief,
    FilterConfig,
    UpdateInfo,
    clip_consistency,
    empty,
    gate_threshold,
    stereo_r,
)
from thinkfast.estimate.motion import process_noise, transition, two_point


def predict(belief: Belief, t: float, cfg: FilterConfig) -> Belief:
    """Predict the belief to time ``t`` [s] (no measurement: e.g. a missing frame).

    Returns the belief unchanged when it is not initialised or ``t`` is not after its time.
    """
    dt = t - belief.t
    if belief.n_meas < 2 or not dt > 0.0:
        return belief
    mean, cov = _propagate(belief.mean, belief.cov, dt, cfg)
    return belief._replace(t=float(t), mean=mean, cov=0.5 * (cov + cov.T))


def _propagate(mean, cov, dt: float, cfg: FilterConfig) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance ``dt`` [s] later (covariance not yet symmetrised)."""
    mean, f = transition(mean, dt, cfg.gravity, cfg.drag)
    return mean, f @ cov @ f.T + process_noise(dt, cfg.accel_psd)


def update(
    belief: Belief,
    t: float,
    z: np.ndarray,
    cfg: FilterConfig,
    sensor: np.ndarray | None = None,
    max_lag: float = 0.0,
) -> tuple[Belief, UpdateInfo]:
    """Fuse the position measurement ``z`` [m], shape (3,), stamped ``t`` [s].

    With ``sensor`` (the camera origin in base [m], shape (3,)) and the stereo model on, the
    measurement noise is the range-dependent stereo model plus the adapted R, which then
    estimates only what the model does not explain (eq. 5 minus the model's mean share).

    ``max_lag`` [s] (several cameras): a measurement older than the belief by at most this is
    fused out of sequence (module doc); 0 (one camera) rejects every one as late.

    Returns:
        The new belief (time ``t``) and an :class:`UpdateInfo`. A late, duplicated or
        out-of-order measurement returns the same belief with ``n_late`` incremented.
    """
    if t <= belief.t_meas or t < belief.t:
        newest = max(belief.t, belief.t_meas)
        if max_lag > 0.0 and belief.n_meas >= 1 and newest - max_lag <= t:
            past = _update_past(belief, t, np.array(z, dtype=float), cfg, sensor)
            if past is not None:
                return past
        return belief._replace(n_late=belief.n_late + 1), UpdateInfo(
            STATUS_LATE, _ZERO3, _ZERO3, 0.0, _NO3
        )
    z = np.array(z, dtype=float)
    r_model = stereo_r(z, sensor, cfg)
    wm = belief.window_model
    if belief.n_meas == 0:
        first = belief._replace(
            t=float(t), mean=np.concatenate([z, _ZERO3]), t_meas=float(t), z_meas=z, n_meas=1,
            s_meas=sensor,
        )  # fmt: skip
        return first, UpdateInfo(STATUS_FIRST, _ZERO3, _ONE3, 0.0, _NO3)
    r_prev = _prev_r(belief, sensor, cfg)
    if belief.n_meas == 1:
        r_init = belief.r + r_model
        mean, cov = two_point(belief.z_meas, z, t - belief.t_meas, r_init, cfg.gravity, cfg.drag)
        _mixed_start(cov, r_prev, r_init, t - belief.t_meas)
        cov += np.diag(np.square(cfg.p0_std))
        init = belief._replace(
            t=float(t), mean=mean, cov=cov, t_meas=float(t), z_meas=z, n_meas=2, s_meas=sensor
        )
        return init, UpdateInfo(STATUS_INIT, _ZERO3, _ONE3, 0.0, _NO3)

    prior_mean, p = belief.mean, belief.cov
    if t > belief.t:
        prior_mean, p = _propagate(prior_mean, p, t - belief.t, cfg)
    hph = p[:3, :3]
    innov = z - prior_mean[:3]
    s = hph + belief.r + r_model
    s_inv = _inv_sym3(s)
    nis = float(innov @ s_inv @ innov)
    keep, weight, gated = _ONE3, _ONE3, np.zeros(3, dtype=np.intp)
    if cfg.robust:
        keep, weight, gated = _gate(innov, s, belief.gated, cfg)

    r, window, n_innov = belief.r, belief.window, belief.n_innov
    if cfg.adaptive and hph.trace() <= r.trace() + r_model.trace():
        window, wm = window.copy(), wm.copy()
        window[n_innov % cfg.window] = keep * innov
        wm[n_innov % cfg.window] = np.diagonal(r_model)
        n_innov += 1
    filled = min(n_innov, cfg.window)
    if cfg.adaptive and filled > 0:
        rows = window if filled == cfg.window else window[:filled]
        model = (wm if filled == cfg.window else wm[:filled]).mean(axis=0)
        c_diag = np.einsum("ij,ij->j", rows, rows) / filled
        r = adapted_r(c_diag, np.diagonal(hph) + model, filled, cfg)
        s_inv = _inv_sym3(hph + r + r_model)

    gain = p[:, :3] @ s_inv  # P H^T S^-1
    mean = prior_mean + gain @ (weight * innov)
    cov = p - gain @ p[:3, :]
    cov = 0.5 * (cov + cov.T)
    reset = gated >= cfg.reset_after
    if cfg.reset_all_axes and reset.any():
        reset = np.ones(3, dtype=bool)
    if reset.any():
        mean, cov = _reinit_axes(
            mean, cov, reset, belief.z_meas, z, t - belief.t_meas, r + r_model, cfg,
            None if r_prev is None else r + r_prev,
        )  # fmt: skip
        gated = np.where(reset, 0, gated)
        # the gated innovations of a manoeuvre (a release) are not measurement noise: forget
        # them on the restarted axes, or R stays inflated for a whole window
        window, wm = window.copy(), wm.copy()
        window[:, reset] = 0.0
        wm[:, reset] = 0.0
    new = belief._replace(
        t=float(t),
        mean=mean,
        cov=cov,
        r=r,
        window=window,
        n_innov=n_innov,
        t_meas=float(t),
        z_meas=z,
        gated=gated,
        n_meas=belief.n_meas + 1,
        n_outliers=belief.n_outliers + int(np.count_nonzero(weight < 1.0)),
        n_resets=belief.n_resets + int(np.count_nonzero(reset)),
        window_model=wm,
        s_meas=sensor,
    )
    return new, UpdateInfo(STATUS_UPDATED, innov, weight, nis, reset)


def _prev_r(belief: Belief, sensor: np.ndarray | None, cfg: FilterConfig) -> np.ndarray | None:
    """Stereo noise [m^2] (3, 3) of the newest measurement when another sensor took it than
    ``sensor``, else None (the same sensor: both share the current noise, as with one camera)."""
    prev = belief.s_meas
    if prev is None or sensor is None or np.array_equal(prev, sensor):
        return None
    return stereo_r(belief.z_meas, prev, cfg)


def _mixed_start(cov: np.ndarray, r_prev: np.ndarray | None, r_new: np.ndarray, dt: float):
    """Two-point start from two sensors: velocity variance ``(R_0 + R_1) / dt^2`` (in place;
    ``r_prev`` the first one's total noise, None: the same sensor, nothing to change)."""
    if r_prev is not None:
        cov[3:, 3:] = (r_prev + r_new) / (dt * dt)


def _update_past(
    belief: Belief, t: float, z: np.ndarray, cfg: FilterConfig, sensor: np.ndarray | None
) -> tuple[Belief, UpdateInfo] | None:
    """Out-of-sequence update with a measurement ``z`` [m] stamped ``t`` [s] before the belief's
    newest (module doc); None when it cannot be used (same stamp as the only measurement)."""
    r_model = stereo_r(z, sensor, cfg)
    if belief.n_meas == 1:  # the older of the first two: start from it and the newer one
        dt = belief.t_meas - t
        if not dt > 0.0:
            return None
        r_new = belief.r + _model_or(belief, cfg)
        mean, cov = two_point(z, belief.z_meas, dt, r_new, cfg.gravity, cfg.drag)
        _mixed_start(cov, belief.r + r_model, r_new, dt)
        cov += np.diag(np.square(cfg.p0_std))
        init = belief._replace(mean=mean, cov=cov, n_meas=2)
        return init, UpdateInfo(STATUS_INIT, _ZERO3, _ONE3, 0.0, _NO3)
    dt = belief.t - t
    mean_b, f_b = transition(belief.mean, -dt, cfg.gravity, cfg.drag)
    h = f_b[:3, :]  # the measurement of the current state through the backward transition
    p = belief.cov
    ph = p @ h.T
    s = h @ ph + belief.r + r_model + process_noise(dt, cfg.accel_psd)[:3, :3]
    innov = z - mean_b[:3]
    s_inv = _inv_sym3(s)
    nis = float(innov @ s_inv @ innov)
    weight = _ONE3
    if cfg.robust:
        weight = _gate(innov, s, np.zeros(3, dtype=np.intp), cfg)[1]
    gain = ph @ s_inv
    mean = belief.mean + gain @ (weight * innov)
    cov = p - gain @ ph.T
    new = belief._replace(
        mean=mean,
        cov=0.5 * (cov + cov.T),
        n_meas=belief.n_meas + 1,
        n_outliers=belief.n_outliers + int(np.count_nonzero(weight < 1.0)),
    )
    return new, UpdateInfo(STATUS_PAST, innov, weight, nis, _NO3)


def _model_or(belief: Belief, cfg: FilterConfig) -> np.ndarray:
    """Stereo noise [m^2] (3, 3) of the newest measurement, from its own sensor."""
    return stereo_r(belief.z_meas, belief.s_meas, cfg)


def restart(
    belief: Belief, t: float, mean: np.ndarray, cov: np.ndarray, z: np.ndarray, sensor=None
) -> Belief:
    """Restart the belief from an outside state estimate at time ``t`` [s] (e.g. a launch fit;
    ``z`` [m] its newest measurement, taken from ``sensor`` (None: the newest one's sensor)).

    The adapted measurement noise R is kept; the innovations in the window are forgotten (they
    belong to the motion before the restart) and the outlier counters start afresh.
    """
    window = np.zeros_like(belief.window)
    wm = np.zeros_like(belief.window_model)
    return belief._replace(
        t=float(t),
        mean=np.array(mean, dtype=float),
        cov=0.5 * (cov + cov.T),
        window=window,
        window_model=wm,
        t_meas=float(t),
        z_meas=np.array(z, dtype=float),
        gated=np.zeros(3, dtype=np.intp),
        n_meas=max(belief.n_meas, 2),
        n_resets=belief.n_resets + 3,
        s_meas=belief.s_meas if sensor is None else sensor,
    )


def adapted_r(c_diag: np.ndarray, hph_diag: np.ndarray, n: int, cfg: FilterConfig) -> np.ndarray:
    """R from the innovation window (eq. 5, diagonal, blended with R0; see the module doc).

    Args:
        c_diag: mean squared revised innovation per axis over the window [m^2], shape (3,).
        hph_diag: diagonal of the predicted position covariance H P- H^T [m^2], shape (3,).
        n: innovations in the window.
        cfg: filter configuration (r0_std, warmup, r_min_std).

    Returns:
        Diagonal R [m^2], shape (3, 3).
    """
    if cfg.robust:
        c_diag = c_diag / clip_consistency(cfg.alpha)
    r0 = _r0_var(cfg)
    w0 = cfg.warmup * (1.0 - n / cfg.window)
    r = (w0 * r0 + n * (c_diag - hph_diag)) / (w0 + n)
    return np.diag(np.maximum(r, cfg.r_min_std * cfg.r_min_std))


@functools.lru_cache(maxsize=16)
def _r0_var(cfg: FilterConfig) -> np.ndarray:
    out = np.square(cfg.r0_std)
    out.setflags(write=False)
    return out


def _gate(innov, s, gated, cfg: FilterConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 3 per axis: (window factor, state-update factor, consecutive-gate counters)."""
    c = gate_threshold(cfg.alpha)
    norm = np.abs(innov) / np.sqrt(np.diagonal(s))
    out = norm > c
    if not out.any():
        return _ONE3, _ONE3, np.zeros(3, dtype=np.intp)
    clip = np.where(out, c / np.maximum(norm, c), 1.0)
    keep = clip * np.exp(np.minimum(cfg.gross_sigma - norm, 0.0) / cfg.shrink_scale)
    weight = clip * np.exp(np.minimum(c - norm, 0.0) / cfg.shrink_scale)
    return keep, weight, np.where(out, gated + 1, 0)


def _reinit_axes(mean, cov, axes, z_prev, z, dt, r, cfg: FilterConfig, r_prev=None):
    """Restart the given axes (bool (3,)) from their last two measurements (see module doc;
    ``r_prev``: the older one's noise when another sensor took it)."""
    fresh, block = two_point(z_prev, z, dt, r, cfg.gravity, cfg.drag)
    _mixed_start(block, r_prev, r, dt)
    block += np.diag(np.square(cfg.p0_std))
    idx = np.flatnonzero(np.concatenate([axes, axes]))
    mean = mean.copy()
    mean[idx] = fresh[idx]
    cov = cov.copy()
    cov[idx, :] = 0.0
    cov[:, idx] = 0.0
    cov[np.ix_(idx, idx)] = block[np.ix_(idx, idx)]
    return mean, cov


def _inv_sym3(s: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite 3 x 3 matrix (adjugate; cheap for tiny input)."""
    (a, b, c), (_, d, e), (_, _, f) = s.tolist()
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * c00 + b * c01 + c * c02
    return (
        np.array(
            [
                [c00, c01, c02],
                [c01, a * f - c * c, b * c - a * e],
                [c02, b * c - a * e, a * d - b * b],
            ]
        )
        / det
    )
