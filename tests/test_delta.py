"""Delta method (thinkfast.estimate.crossing): plane crossing, its Jacobian and covariance."""

from __future__ import annotations

import warnings

import numpy as np

from thinkfast.estimate.crossing import REASON_PAST, REASON_RECEDING, crossing, crossing_point

G = 9.81
PLANE = 0.8


def random_state(rng):
    return np.array(
        [
            rng.uniform(2.0, 8.0),
            rng.uniform(-1, 1),
            rng.uniform(0.5, 2.0),
            rng.uniform(-20.0, -6.0),
            rng.uniform(-2, 2),
            rng.uniform(-3, 6),
        ]
    )


def test_jacobian_matches_central_finite_differences_to_1e6_relative():
    rng = np.random.default_rng(1)
    for _ in range(50):
        s = random_state(rng)
        jac = crossing(s, np.eye(6), PLANE, G).jac
        num = np.zeros((3, 6))
        for j in range(6):
            h = 1e-6 * max(1.0, abs(s[j]))
            e = np.zeros(6)
            e[j] = h
            num[:, j] = (crossing_point(s + e, PLANE, G) - crossing_point(s - e, PLANE, G)) / (
                2 * h
            )
        scale = np.maximum(np.abs(num), 1e-3 * np.abs(num).max(axis=1, keepdims=True))
        assert np.max(np.abs(jac - num) / scale) < 1e-6


def test_crossing_point_is_where_the_simulated_ballistic_flight_meets_the_plane():
    rng = np.random.default_rng(2)
    for _ in range(20):
        s = random_state(rng)
        y, z, tau = crossing_point(s, PLANE, G)
        # integrate the flight and find the crossing independently
        t = np.linspace(0.0, 2.0 * tau, 200001)
        x = s[0] + s[3] * t
        i = np.argmin(np.abs(x - PLANE))
        assert abs(t[i] - tau) < 2e-5
        assert abs(s[1] + s[4] * t[i] - y) < 1e-4
        assert abs(s[2] + s[5] * t[i] - 0.5 * G * t[i] ** 2 - z) < 1e-3


def test_output_covariance_matches_a_monte_carlo_when_the_state_is_tight():
    rng = np.random.default_rng(3)
    for _ in range(5):
        s = random_state(rng)
        a = rng.normal(size=(6, 6))
        cov = a @ a.T * 1e-6 + np.diag([4e-4, 1e-4, 1e-4, 2e-2, 1e-2, 1e-2])  # cm, 0.1 m/s
        c = crossing(s, cov, PLANE, G)
        samples = rng.multivariate_normal(s, cov, size=100_000)
        x, y, z, vx, vy, vz = samples.T
        tau = (PLANE - x) / vx
        out = np.column_stack([y + vy * tau, z + vz * tau - 0.5 * G * tau * tau, tau])
        mc = np.cov(out.T)
        sd, sd_mc = np.sqrt(np.diag(c.cov)), np.sqrt(np.diag(mc))
        np.testing.assert_allclose(c.cov.diagonal(), mc.diagonal(), rtol=0.05)
        corr = c.cov / np.outer(sd, sd)
        corr_mc = mc / np.outer(sd_mc, sd_mc)
        np.testing.assert_allclose(corr, corr_mc, atol=0.05)
        np.testing.assert_allclose(c.mean, out.mean(axis=0), atol=0.05 * sd.max())


def test_receding_or_hovering_ball_has_no_crossing_and_no_division_by_zero():
    s = np.array([5.0, 0.0, 1.0, 0.0, 1.0, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for vx in (0.0, 3.0, -0.05, -0.0):
            s[3] = vx
            c = crossing(s, np.eye(6), PLANE, G)
            assert not c.ok and c.reason == REASON_RECEDING
            assert np.all(np.isfinite(c.mean)) and np.all(c.cov == 0.0)


def test_crossing_already_behind_the_ball_is_reported_as_past():
    s = np.array([0.5, 0.0, 1.0, -10.0, 0.0, 0.0])
    c = crossing(s, np.eye(6), PLANE, G)
    assert not c.ok and c.reason == REASON_PAST


def test_tau_is_measured_from_the_belief_time():
    s = np.array([PLANE + 5.0, 0.0, 1.0, -10.0, 0.0, 0.0])
    c = crossing(s, np.eye(6) * 1e-6, PLANE, G)
    assert c.ok and abs(c.mean[2] - 0.5) < 1e-12
