"""RIAE-AKF (thinkfast.estimate.filter) and its motion model (thinkfast.estimate.motion)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from thinkfast.config import from_dict
from thinkfast.errors import ConfigError
from thinkfast.estimate import filter as kf
from thinkfast.estimate.crossing import crossing
from thinkfast.estimate.motion import process_noise, transition

G = 9.81
PLANE = 0.8


def simulate_throw(rng, sigma=0.03, q=0.0, drag=0.0, outliers=0.0, triple_at=None, rate=50.0):
    """One throw from 6-8 m towards the plane x = PLANE, 0.4-0.8 s flight, sampled at ``rate``.

    Returns (stamps (K,), measurements (K, 3), true states (K, 6)). Truth integrates gravity,
    optional drag and white acceleration of spectral density q in 10 sub-steps per frame.
    Measurement noise is N(0, sigma^2) per axis (tripled from frame ``triple_at`` on); with
    probability ``outliers`` a frame (from the third on) is replaced by a point 0.3-1.0 m away.
    """
    x0, flight = rng.uniform(6.0, 8.0), rng.uniform(0.4, 0.8)
    target = np.array([PLANE, rng.uniform(-0.7, 0.7), rng.uniform(0.5, 1.6)])
    p = np.array([x0 + PLANE, rng.uniform(-0.5, 0.5), rng.uniform(1.0, 2.0)])
    v = (target - p) / flight
    v[2] += 0.5 * G * flight
    dt, sub = 1.0 / rate, 10
    h = dt / sub
    stamps, zs, states = [], [], []
    k = 0
    while True:
        states.append(np.concatenate([p, v]))
        stamps.append(k * dt)
        s = sigma * (3.0 if triple_at is not None and k >= triple_at else 1.0)
        z = p + rng.normal(0.0, s, 3)
        if k >= 2 and rng.random() < outliers:
            d = rng.normal(size=3)
            z = p + d / np.linalg.norm(d) * rng.uniform(0.3, 1.0)
        zs.append(z)
        if p[0] < PLANE:
            break
        for _ in range(sub):
            a = np.array([0.0, 0.0, -G]) - drag * np.linalg.norm(v) * v
            if q > 0.0:
                a = a + rng.normal(0.0, np.sqrt(q / h), 3)
            p, v = p + v * h + 0.5 * a * h * h, v + a * h
        k += 1
    return np.array(stamps), np.array(zs), np.array(states)


def true_crossing(stamps, states):
    """(time, Y, Z) where the simulated ball crosses the plane (ballistic within one frame)."""
    i = np.flatnonzero(states[:, 0] < PLANE)[0] - 1
    x = states[i]
    tau = (PLANE - x[0]) / x[3]
    return stamps[i] + tau, x[1] + x[4] * tau, x[2] + x[5] * tau - 0.5 * G * tau * tau


def run(cfg, stamps, zs):
    belief, out = kf.empty(cfg), []
    for t, z in zip(stamps, zs, strict=True):
        belief, _ = kf.update(belief, t, z, cfg)
        out.append(belief)
    return out


def textbook_kf(stamps, zs, q, r0):
    """Reference linear KF: two-point start, F/Q/H textbook forms, P = (I - K H) P-."""
    dt0 = stamps[1] - stamps[0]
    grav = np.array([0.0, 0.0, -G])
    r = np.diag(r0)
    x = np.concatenate([zs[1], (zs[1] - zs[0]) / dt0 + 0.5 * dt0 * grav])
    p = np.block([[r, r / dt0], [r / dt0, 2.0 * r / dt0**2]])
    h = np.hstack([np.eye(3), np.zeros((3, 3))])
    out = [None, (x, p)]
    for t_prev, t, z in zip(stamps[1:-1], stamps[2:], zs[2:], strict=True):
        dt = t - t_prev
        f = np.eye(6)
        f[:3, 3:] = dt * np.eye(3)
        u = np.concatenate([0.5 * dt * dt * grav, dt * grav])
        qd = np.block(
            [
                [np.diag(q) * dt**3 / 3, np.diag(q) * dt**2 / 2],
                [np.diag(q) * dt**2 / 2, np.diag(q) * dt],
            ]
        )
        x = f @ x + u
        p = f @ p @ f.T + qd
        s = h @ p @ h.T + r
        k = p @ h.T @ np.linalg.inv(s)
        x = x + k @ (z - h @ x)
        p = (np.eye(6) - k @ h) @ p
        out.append((x, p))
    return out


def test_textbook_kalman_filter_equivalence_to_1e10_with_adaptation_and_gating_off():
    rng = np.random.default_rng(11)
    for _ in range(20):
        n = int(rng.integers(5, 60))
        stamps = np.cumsum(rng.uniform(0.005, 0.05, n))  # variable dt
        zs = rng.normal(0.0, 2.0, (n, 3))  # arbitrary sequences, not just throws
        q = rng.uniform(0.01, 20.0, 3)
        r0 = rng.uniform(0.005, 0.1, 3)
        cfg = kf.FilterConfig(
            accel_psd=tuple(q),
            r0_std=tuple(np.sqrt(r0)),
            p0_std=(0.0,) * 6,
            robust=False,
            adaptive=False,
        )
        ours, ref = run(cfg, stamps, zs), textbook_kf(stamps, zs, q, r0)
        for b, (x, p) in zip(ours[1:], ref[1:], strict=True):
            assert np.max(np.abs(b.mean - x)) <= 1e-10 * max(1.0, np.max(np.abs(x)))
            assert np.max(np.abs(b.cov - p)) <= 1e-10 * max(1.0, np.max(np.abs(p)))


def test_mean_nees_inside_95_percent_chi_square_band_on_simulated_throws():
    rng = np.random.default_rng(3)
    q, sigma, runs = 0.5, 0.03, 100
    base = dict(accel_psd=(q,) * 3, r0_std=(sigma,) * 3, p0_std=(0.0,) * 6)
    throws = [simulate_throw(rng, sigma=sigma, q=q) for _ in range(runs)]
    lo, hi = chi2.ppf(0.025, 6 * runs) / runs, chi2.ppf(0.975, 6 * runs) / runs
    for cfg in (kf.FilterConfig(**base), kf.FilterConfig(**base, robust=False, adaptive=False)):
        per_step = {}
        for stamps, zs, states in throws:
            for k, b in enumerate(run(cfg, stamps, zs)):
                if k >= 2:
                    e = b.mean - states[k]
                    per_step.setdefault(k, []).append(e @ np.linalg.solve(b.cov, e))
        run_avg = [np.mean(v) for v in per_step.values() if len(v) == runs]
        assert lo < np.mean(run_avg) < hi, (cfg.adaptive, np.mean(run_avg), lo, hi)


def crossing_errors(cfg, throws, lead=0.15):
    errors = []
    for stamps, zs, states in throws:
        t_cross, y, z = true_crossing(stamps, states)
        beliefs = run(cfg, stamps, zs)
        b = beliefs[np.flatnonzero(stamps <= t_cross - lead)[-1]]
        c = crossing(b.mean, b.cov, PLANE, G)
        errors.append(np.hypot(c.mean[0] - y, c.mean[1] - z) if c.ok else 10.0)
    return np.array(errors)


def test_gross_outliers_halve_the_crossing_error_150ms_before_crossing():
    rng = np.random.default_rng(0)
    throws = [simulate_throw(rng, sigma=0.03, outliers=0.05) for _ in range(120)]
    base = dict(accel_psd=(1e-4,) * 3, r0_std=(0.03,) * 3)
    riae = crossing_errors(kf.FilterConfig(**base), throws)
    plain = crossing_errors(kf.FilterConfig(**base, robust=False, adaptive=False), throws)
    assert riae.mean() <= 0.5 * plain.mean(), (riae.mean(), plain.mean())


def test_measurement_noise_tripling_mid_throw_is_followed_by_r_within_one_window():
    rng = np.random.default_rng(7)
    sigma, switch = 0.03, 12
    cfg = kf.FilterConfig(accel_psd=(0.5,) * 3, r0_std=(sigma,) * 3)
    before, after = [], []
    while len(after) < 40:
        stamps, zs, _ = simulate_throw(rng, sigma=sigma, q=0.5, triple_at=switch)
        if len(stamps) <= switch + cfg.window:
            continue
        beliefs = run(cfg, stamps, zs)
        before.append(np.sqrt(np.diag(beliefs[switch - 1].r)) / sigma)
        after.append(np.sqrt(np.diag(beliefs[switch + cfg.window].r)) / (3.0 * sigma))
    assert 0.8 <= np.median(before) <= 1.2
    assert 0.8 <= np.median(after) <= 1.2, np.median(after, axis=0)


def test_a_single_gross_outlier_is_shrunk_to_almost_nothing():
    rng = np.random.default_rng(5)
    stamps, zs, states = simulate_throw(rng, sigma=0.01)
    cfg = kf.FilterConfig(accel_psd=(0.1,) * 3, r0_std=(0.01,) * 3)
    beliefs = run(cfg, stamps[:15], zs[:15])
    bad = zs[15] + np.array([0.0, 0.8, 0.0])
    after, info = kf.update(beliefs[-1], stamps[15], bad, cfg)
    assert info.weight[1] < 1e-6 and info.weight[0] == 1.0 and info.weight[2] == 1.0
    assert abs(after.mean[1] - states[15][1]) < 0.05
    assert after.n_outliers == beliefs[-1].n_outliers + 1


def test_lost_axis_recovers_by_reinitialising_after_reset_after_gated_updates():
    rng = np.random.default_rng(2)
    stamps, zs, states = simulate_throw(rng, sigma=0.01)
    cfg = kf.FilterConfig(accel_psd=(0.1,) * 3, r0_std=(0.01,) * 3)
    beliefs = run(cfg, stamps[:8], zs[:8])
    lost = beliefs[-1]._replace(mean=beliefs[-1].mean + np.array([0, 0, 0.5, 0, 0, 3.0]))
    b, resets = lost, 0
    for t, z in zip(stamps[8:], zs[8:], strict=False):
        b, info = kf.update(b, t, z, cfg)
        resets += int(info.reset.sum())
    assert resets >= 1 and b.n_resets >= 1
    assert abs(b.mean[2] - states[len(stamps) - 1][2]) < 0.05


def test_a_gross_outlier_in_the_initialising_frame_is_replaced_within_a_few_frames():
    cfg = kf.FilterConfig(accel_psd=(0.5,) * 3, r0_std=(0.02,) * 3)
    for seed in range(20):
        stamps, zs, states = simulate_throw(np.random.default_rng(seed), sigma=0.02)
        zs = zs.copy()
        zs[0] += np.array([0.0, 0.6, -0.4])
        b = run(cfg, stamps[:11], zs[:11])[-1]
        assert b.n_resets >= 2
        assert np.linalg.norm(b.mean[:3] - states[10][:3]) < 0.1


def test_late_duplicate_and_out_of_order_measurements_never_touch_the_state():
    rng = np.random.default_rng(4)
    stamps, zs, _ = simulate_throw(rng)
    cfg = kf.FilterConfig()
    b = run(cfg, stamps[:10], zs[:10])[-1]
    for t in (stamps[9], stamps[5], stamps[9] - 1e-6):
        late, info = kf.update(b, t, zs[3], cfg)
        assert info.status == kf.STATUS_LATE
        assert late.mean is b.mean and late.cov is b.cov and late.r is b.r
        assert late.n_late == b.n_late + 1
    ahead = kf.predict(b, stamps[9] + 0.05, cfg)
    late, info = kf.update(ahead, stamps[9] + 0.03, zs[10], cfg)  # older than the belief
    assert info.status == kf.STATUS_LATE and late.mean is ahead.mean
    assert kf.predict(b, stamps[9] - 0.01, cfg) is b  # never predicts backwards


def test_missing_frame_predict_then_update_equals_direct_update():
    rng = np.random.default_rng(8)
    stamps, zs, _ = simulate_throw(rng)
    cfg = kf.FilterConfig(robust=False, adaptive=False)
    b = run(cfg, stamps[:6], zs[:6])[-1]
    direct, _ = kf.update(b, stamps[7], zs[7], cfg)
    via, _ = kf.update(kf.predict(b, stamps[6], cfg), stamps[7], zs[7], cfg)
    np.testing.assert_allclose(via.mean, direct.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(via.cov, direct.cov, rtol=1e-9, atol=1e-15)


def test_two_point_start_gives_the_velocity_at_the_second_stamp_with_the_right_sign():
    p0, v0, dt = np.array([7.0, 0.2, 1.5]), np.array([-12.0, 0.5, 3.0]), 0.02
    p1 = p0 + v0 * dt + 0.5 * np.array([0, 0, -G]) * dt * dt
    cfg = kf.FilterConfig()
    b, info = kf.update(kf.empty(cfg), 1.0, p0, cfg)
    assert info.status == kf.STATUS_FIRST and b.n_meas == 1
    b, info = kf.update(b, 1.0 + dt, p1, cfg)
    assert info.status == kf.STATUS_INIT
    np.testing.assert_allclose(b.mean[3:], v0 + np.array([0, 0, -G]) * dt, atol=1e-9)
    assert b.mean[3] < 0.0  # approaching: x decreases


def test_drag_free_transition_is_exact_ballistics():
    mean = np.array([7.0, 0.1, 1.4, -11.0, 0.3, 2.0])
    new, f = transition(mean, 0.3, G, 0.0)
    t = 0.3
    expect = mean[:3] + mean[3:] * t + 0.5 * np.array([0, 0, -G]) * t * t
    np.testing.assert_allclose(new[:3], expect, atol=1e-12)
    np.testing.assert_allclose(f[:3, 3:], t * np.eye(3), atol=0)


def test_drag_transition_jacobian_matches_finite_differences():
    rng = np.random.default_rng(9)
    for _ in range(10):
        mean = np.concatenate([rng.uniform(1, 8, 3), rng.uniform(-15, 5, 3)])
        dt, k = 0.02, 0.012
        _, f = transition(mean, dt, G, k)
        num = np.zeros((6, 6))
        for j in range(6):
            e = np.zeros(6)
            e[j] = 1e-6
            num[:, j] = (
                transition(mean + e, dt, G, k)[0] - transition(mean - e, dt, G, k)[0]
            ) / 2e-6
        np.testing.assert_allclose(f, num, atol=2e-5)


def test_drag_model_estimates_a_dragged_throw_better_than_the_paper_model():
    rng = np.random.default_rng(12)
    throws = [simulate_throw(rng, sigma=0.02, drag=0.012) for _ in range(30)]
    base = dict(accel_psd=(0.05,) * 3, r0_std=(0.02,) * 3)

    def velocity_rms(cfg):
        err = [
            b.mean[3:] - x[3:]
            for stamps, zs, states in throws
            for b, x in list(zip(run(cfg, stamps, zs), states, strict=True))[8:]
        ]
        return np.sqrt(np.mean(np.square(err)))

    assert velocity_rms(kf.FilterConfig(**base, drag=0.012)) < 0.7 * velocity_rms(
        kf.FilterConfig(**base)
    )


def test_process_noise_is_the_white_acceleration_discretisation():
    q, dt = np.array([1.0, 2.0, 3.0]), 0.02
    out = process_noise(dt, q)
    for i in range(3):
        block = out[np.ix_([i, i + 3], [i, i + 3])]
        np.testing.assert_allclose(
            block, q[i] * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        )
    assert np.count_nonzero(out) == 12


def test_config_loads_from_a_toml_table_and_names_bad_keys():
    cfg = from_dict(
        kf.FilterConfig, {"alpha": 0.95, "window": 12, "drag": 0.01}, "run.toml", "filter"
    )
    assert cfg.alpha == 0.95 and cfg.window == 12 and dataclasses.is_dataclass(cfg)
    with pytest.raises(ConfigError, match="filter.windw"):
        from_dict(kf.FilterConfig, {"windw": 3}, "run.toml", "filter")
    with pytest.raises(ConfigError, match="filter.r0_std"):
        from_dict(kf.FilterConfig, {"r0_std": [0.01, 0.01]}, "run.toml", "filter")
