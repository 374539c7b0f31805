"""The isotropic disk table (thinkfast.decide.iso_disk) against the Marcum Q function and the
disk masses of thinkfast.decide.shield_disk."""

from __future__ import annotations

import numpy as np
from scipy.special import chndtr

from thinkfast.decide import iso_disk
from thinkfast.decide.values import ValueConfig, layout, terminal_values


def test_lookups_match_the_noncentral_chi_square_cdf_to_5e5():
    """Random radii, offsets and sigmas from 0.3 mm to 3 m (b = rho / sigma from 0.02 to 1000)."""
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(200):
        sigma, rho = 10 ** rng.uniform(-3.5, 0.5), rng.uniform(0.05, 0.4)
        d = np.abs(np.r_[rho + sigma * rng.uniform(-9, 9, 100), rng.uniform(0, 2 * rho, 30)])
        got = iso_disk.disk_probability(d, rho, sigma)
        ref = chndtr((rho / sigma) ** 2, 2, (d / sigma) ** 2)
        worst = max(worst, float(np.max(np.abs(got - ref))))
    assert worst < 5e-5


def test_lookups_match_the_disk_masses_of_todays_values_to_3e4():
    """An isotropic (Y, Z) belief: the disk.py quadrature and the table agree for goals from the
    centre to beyond the rim."""
    rho = 0.2335
    for sd in (0.004, 0.03, 0.1, 0.4):
        goals = np.column_stack([np.linspace(0.0, rho + 4 * sd, 25), np.full(25, 1.0)])
        cov = np.diag([sd * sd, sd * sd, 1e-4])
        mass = terminal_values(
            layout(goals, np.arange(25), rho, ValueConfig()), np.array([0.0, 1.0, 0.5]), cov,
            np.zeros(25),
        ).goal_mass  # fmt: skip
        got = iso_disk.disk_probability(goals[:, 0], rho, sd)
        assert np.max(np.abs(got - mass)) < 3e-4


def test_rim_tables_are_the_profiles_as_value_and_slope():
    for sigma in (0.001, 0.05, 2.0):
        for radii in (np.array([0.2335]), np.array([0.2, 0.21, 0.2335])):
            value, slope = iso_disk.rim_table(sigma, radii)
            prof = iso_disk.disk_profiles(sigma, radii)
            assert np.allclose(value, prof[:, :-1].ravel(), atol=1e-15)
            assert np.allclose(slope, np.diff(prof, axis=1).ravel(), atol=1e-15)


def test_profiles_are_probabilities_falling_across_the_rim():
    prof = iso_disk.disk_profiles(0.02, np.array([0.2, 0.2335]))
    assert np.all((prof >= 0) & (prof <= 1))
    assert np.all(np.diff(prof, axis=1) <= 1e-12)
    assert prof[:, 0].min() > 1 - 1e-12 and prof[:, -1].max() < 1e-12
