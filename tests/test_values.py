"""Terminal values (thinkfast.decide.values) and disk masses (thinkfast.decide.shield_disk)."""

from __future__ import annotations

import math
import warnings
import zlib

import numpy as np
import pytest
from scipy.special import ndtr

from thinkfast.config import from_dict
from thinkfast.decide.shield_disk import plane_frame
from thinkfast.decide.values import ValueConfig, layout, terminal_values
from thinkfast.errors import ConfigError
from thinkfast.estimate.crossing import crossing

R = 0.15  # shield radius [m]
MARGIN = 0.02


def gaussian(sd, corr):
    """Covariance of (Y, Z, tau) from standard deviations and correlations (ryz, ryt, rzt)."""
    ryz, ryt, rzt = corr
    c = np.array([[1.0, ryz, ryt], [ryz, 1.0, rzt], [ryt, rzt, 1.0]])
    return c * np.outer(sd, sd)


def goal_grid(spacing=0.2):
    gy, gz = np.meshgrid(np.arange(-0.9, 0.9 + 1e-9, spacing), np.arange(0.3, 1.8 + 1e-9, spacing))
    return np.column_stack([gy.ravel(), gz.ravel()])


def delta_belief():
    """A crossing belief produced by the delta method from a realistic early-throw state."""
    state = np.array([5.8, 0.1, 1.6, -12.0, 0.4, 2.5])
    cov = np.diag([0.08, 0.01, 0.01, 1.5, 0.2, 0.2]) ** 2
    cov[0, 3] = cov[3, 0] = 0.6 * 0.08 * 1.5
    c = crossing(state, cov, 0.8, 9.81)
    return c.mean, c.cov


BELIEFS = {
    "strong_y_tau": (np.array([0.05, 1.0, 0.5]), gaussian([0.2, 0.05, 0.05], [0.0, 0.999, 0.0])),
    "strong_z_tau": (np.array([0.0, 1.1, 0.5]), gaussian([0.03, 0.3, 0.08], [0.0, 0.0, 0.9995])),
    "tight": (np.array([0.02, 1.01, 0.4]), gaussian([0.005, 0.005, 0.002], [0.0, 0.3, 0.5])),
    "tight_at_edge": (
        np.array([0.1 + R, 1.1, 0.4]),
        gaussian([0.005, 0.005, 0.002], [0.0, 0.8, 0.0]),
    ),
    "tight_at_edge_correlated": (
        np.array([0.1 + R / math.sqrt(2), 1.1 + R / math.sqrt(2), 0.4]),
        gaussian([0.005, 0.005, 0.001], [0.2, 0.99, 0.3]),
    ),
    "wide": (np.array([0.1, 1.0, 0.5]), gaussian([0.5, 0.5, 0.1], [0.0, 0.0, 0.0])),
    "wide_correlated": (np.array([0.1, 1.0, 0.5]), gaussian([0.5, 0.4, 0.1], [0.2, 0.9, 0.3])),
    "medium": (np.array([0.3, 0.8, 0.45]), gaussian([0.08, 0.1, 0.03], [0.2, 0.6, -0.5])),
    "from_delta_method": delta_belief(),
}


def monte_carlo(mean, cov, goals, term_goal, t, n, rng):
    """P(|(Y, Z) - g| <= R and tau > t) for every terminal, from n samples."""
    s = rng.multivariate_normal(mean, cov, size=n)
    out = np.zeros(len(term_goal))
    for g in np.unique(term_goal):
        inside = np.hypot(s[:, 0] - goals[g, 0], s[:, 1] - goals[g, 1]) <= R
        taus = np.sort(s[inside, 2])
        sel = term_goal == g
        out[sel] = (len(taus) - np.searchsorted(taus, t[sel], side="right")) / n
    return out


@pytest.mark.parametrize("name", sorted(BELIEFS))
def test_terminal_values_match_a_million_sample_monte_carlo_within_0005(name):
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    mean, cov = BELIEFS[name]
    goals = np.vstack([goal_grid(), [[0.1, 1.1]]])  # the last goal is the one at the edge
    near = np.argsort(np.hypot(*(goals - mean[:2]).T))[:12]
    term_goal = np.repeat(near, 25)
    sd_tau = math.sqrt(cov[2, 2])
    remaining = mean[2] + sd_tau * rng.uniform(-4.0, 4.0, len(term_goal)) - MARGIN
    lay = layout(goals, term_goal, R, ValueConfig(margin=MARGIN))
    got = terminal_values(lay, mean, cov, remaining)
    ref = monte_carlo(mean, cov, goals, term_goal, remaining + MARGIN, 1_000_000, rng)
    assert np.max(np.abs(got.value - ref)) <= 0.005


def test_centred_disk_mass_is_the_rayleigh_probability_to_2e4():
    goals = np.array([[0.0, 1.0]])
    for sd in (0.003, 0.02, 0.05, 0.1, 0.15, 0.6):
        cov = gaussian([sd, sd, 0.01], [0.0, 0.0, 0.0])
        got = terminal_values(
            layout(goals, [0], R, ValueConfig()), np.array([0, 1.0, 0.5]), cov, np.array([-10.0])
        )
        expect = 1.0 - math.exp(-0.5 * (R / sd) ** 2)
        assert abs(got.goal_mass[0] - expect) < 2e-4
        assert abs(got.value[0] - got.goal_mass[0]) < 1e-6  # all of it, within Q(k_time)


def test_without_tau_correlation_value_is_disk_mass_times_the_tau_tail():
    rng = np.random.default_rng(5)
    goals = goal_grid()
    mean = np.array([0.1, 1.0, 0.45])
    cov = gaussian([0.1, 0.15, 0.02], [0.4, 0.0, 0.0])
    term_goal = np.repeat(np.arange(len(goals)), 10)
    remaining = 0.45 + 0.02 * rng.uniform(-5, 5, len(term_goal))
    got = terminal_values(
        layout(goals, term_goal, R, ValueConfig(margin=0.0)), mean, cov, remaining
    )
    expect = got.goal_mass[term_goal] * ndtr(-(remaining - 0.45) / 0.02)
    assert np.max(np.abs(got.value - expect)) < 1e-3


def test_values_are_probabilities_bounded_by_the_disk_mass_and_fall_with_arrival_time():
    rng = np.random.default_rng(6)
    goals = goal_grid()
    for mean, cov in BELIEFS.values():
        term_goal = np.repeat(np.arange(len(goals)), 40)
        remaining = np.tile(np.linspace(-0.5, 1.5, 40), len(goals)) + rng.normal(0, 1e-9)
        got = terminal_values(layout(goals, term_goal, R, ValueConfig()), mean, cov, remaining)
        v = got.value.reshape(len(goals), 40)
        assert np.all(v >= 0.0) and np.all(v <= got.goal_mass[:, None] + 1e-12)
        assert np.all(np.diff(v, axis=1) <= 1e-12)


def test_pruned_goals_are_provably_below_1e9():
    goals = np.array([[0.0, 1.0], [0.8, 1.0], [0.0, 1.6]])
    mean, cov = np.array([0.0, 1.0, 0.5]), gaussian([0.05, 0.05, 0.01], [0.0, 0.3, 0.0])
    got = terminal_values(layout(goals, [0, 1, 2], R, ValueConfig()), mean, cov, np.zeros(3))
    assert got.goal_mass[0] > 0.98  # 1 - exp(-4.5)
    # Goals 1 and 2 start (0.8 - R) / 0.05 = 13 sigma away along one axis.
    assert got.goal_mass[1] == 0.0 and got.goal_mass[2] == 0.0
    assert 2.0 * ndtr(-(0.8 - R) / 0.05) < 1e-9


def test_degenerate_beliefs_give_finite_values_without_warnings():
    goals = goal_grid()
    term_goal = np.arange(len(goals))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for cov in (
            np.zeros((3, 3)),
            np.diag([0.0, 0.01, 1e-4]),
            gaussian([0.1, 0.1, 0.01], [1.0, 1.0, 1.0]),
            np.eye(3) * 1e-20,
        ):
            got = terminal_values(
                layout(goals, term_goal, R, ValueConfig()),
                np.array([0.1, 1.1, 0.4]),
                cov,
                np.full(len(goals), 0.3),
            )
            assert np.all(np.isfinite(got.value)) and np.all(np.isfinite(got.goal_mass))
            assert np.all(got.value <= 1.0 + 1e-9)


def test_plane_frame_reproduces_the_covariance():
    rng = np.random.default_rng(8)
    for _ in range(20):
        a = rng.normal(size=(3, 3))
        cov = a @ a.T * np.outer([0.1, 0.2, 0.02], [0.1, 0.2, 0.02]) + np.eye(3) * 1e-8
        f = plane_frame(np.zeros(3), cov)
        rot = np.array([f.e_u, f.e_w])
        syy = rot @ (cov[:2, :2] + 1e-12 * np.eye(2)) @ rot.T
        assert abs(syy[0, 0] - f.s_u**2) < 1e-12 and abs(syy[1, 1] - f.s_w**2) < 1e-12
        assert abs(syy[0, 1] - f.gamma * f.s_u**2) < 1e-12
        # tau's regression on (u, w) has no w component and slope beta along u.
        coef = np.linalg.solve(syy, rot @ cov[:2, 2])
        assert abs(coef[0] - f.beta) < 1e-9 * max(1.0, f.beta) and abs(coef[1]) < 1e-9


def test_config_loads_from_a_toml_table_and_checks_node_bounds():
    cfg = from_dict(ValueConfig, {"margin": 0.03, "time_points": 96}, "run.toml", "values")
    assert cfg.margin == 0.03 and cfg.time_points == 96
    with pytest.raises(ConfigError, match="max_nodes"):
        from_dict(ValueConfig, {"min_nodes": 40, "max_nodes": 20}, "run.toml", "values")
    with pytest.raises(ConfigError, match="radius"):
        layout(goal_grid(), [0], 0.0, ValueConfig())
