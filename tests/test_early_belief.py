"""The early belief: a velocity prior from the cell's throws, a free flight fitted with it, and
the launch-likely test that starts the hedge stage."""

from __future__ import annotations

import numpy as np

from thinkfast.estimate import early_belief as eb
from thinkfast.estimate.launch import fit_free_flight

G = 9.81
CFG = eb.EarlyConfig()
PLANE_X = 0.8
YZ_LO, YZ_HI = np.array([-0.9, 0.25]), np.array([0.9, 1.6])
HAND = np.array([7.5, 0.2, 1.4])
R = np.diag([0.15**2, 0.007**2, 0.007**2])  # depth 15 cm, lateral 7 mm (about 7 m away)


def _flight(v0, times):
    return np.array([HAND + v0 * t - [0.0, 0.0, 0.5 * G * t * t] for t in times])


def test_velocity_prior_matches_the_moments_of_a_dense_uniform_draw():
    mean, cov = eb.velocity_prior(HAND, PLANE_X, YZ_LO, YZ_HI, (0.4, 0.8), G, 15)
    rng = np.random.default_rng(3)
    y, z = rng.uniform(YZ_LO[0], YZ_HI[0], 200_000), rng.uniform(YZ_LO[1], YZ_HI[1], 200_000)
    t = rng.uniform(0.4, 0.8, 200_000)
    v = np.stack([(PLANE_X - HAND[0]) / t, (y - HAND[1]) / t, (z - HAND[2] + 0.5 * G * t * t) / t])
    np.testing.assert_allclose(mean, v.mean(axis=1), rtol=0.01, atol=0.02)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), v.std(axis=1), rtol=0.03)
    assert mean[0] < -8.0  # every throw of the prior approaches the plane fast


def test_with_many_precise_points_the_prior_hardly_matters():
    times = np.arange(10) * 0.02
    v0 = np.array([-11.0, -0.3, 2.5])
    pts = _flight(v0, times)
    covs = np.repeat((R / 100.0)[None], len(times), axis=0)
    vm, vc = eb.velocity_prior(pts[-1], PLANE_X, YZ_LO, YZ_HI, (0.4, 0.8), G, 5)
    x, cov, c2 = eb.fit_with_prior(times, pts, covs, G, vm, vc)
    free, _, _ = fit_free_flight(times, pts, covs, G)
    np.testing.assert_allclose(x, free[0], atol=0.02)
    np.testing.assert_allclose(x[3:], v0 - [0.0, 0.0, G * times[-1]], atol=0.02)  # at the newest


def test_one_point_gives_a_belief_as_wide_as_the_prior_and_more_points_narrow_it():
    times = np.arange(4) * 0.02
    pts = _flight(np.array([-11.0, -0.3, 2.5]), times)
    covs = np.repeat(R[None], 4, axis=0)
    vm, vc = eb.velocity_prior(pts[0], PLANE_X, YZ_LO, YZ_HI, (0.4, 0.8), G, 5)
    _, cov1, _ = eb.fit_with_prior(times[:1], pts[:1], covs[:1], G, vm, vc)
    np.testing.assert_allclose(cov1[3:, 3:], vc, rtol=1e-9)
    _, cov4, _ = eb.fit_with_prior(times, pts, covs, G, vm, vc)
    assert np.all(np.diag(cov4)[3:] < np.diag(cov1)[3:])


def _points(positions, t0=0.0):
    return [(t0 + 0.02 * i, np.asarray(p, dtype=float), R) for i, p in enumerate(positions)]


def test_a_ball_held_still_is_not_a_likely_launch_and_a_flight_is():
    rng = np.random.default_rng(5)
    held = [HAND + rng.normal(0.0, [0.15, 0.007, 0.007]) for _ in range(40)]
    fired = 0
    for k in range(CFG.min_hold, len(held)):
        fit = eb.early_fit(_points(held[: k + 1]), CFG, PLANE_X, YZ_LO, YZ_HI, G)
        fired += eb.likely_launch(fit, CFG)
    assert fired <= 1  # noise alone: two points in a row 2 sigma nearer the plane is rare
    v0 = np.array([-11.0, -0.3, 2.5])
    flight = [HAND] * 10 + list(_flight(v0, 0.02 * np.arange(1, 5)))
    fit = eb.early_fit(_points(flight), CFG, PLANE_X, YZ_LO, YZ_HI, G)
    # the first flight point (22 cm from the hold) is within 2 depth stds (30 cm): not counted
    assert fit is not None and fit.n == 3 and eb.likely_launch(fit, CFG)
    np.testing.assert_allclose(fit.hold, HAND)


def test_a_hand_moving_the_ball_slowly_towards_the_plane_is_rejected_once_depth_tells():
    """A hand carrying the ball at 1.5 m/s after it left the hold: with 5 cm depth noise (a
    nearer thrower or a side camera) three points tell it from a throw's 8+ m/s; with 15 cm they
    do not (the hedge's bound and time limit are what keep such a motion harmless)."""
    hold = [HAND] * 10
    fine = np.diag([0.05**2, 0.007**2, 0.007**2])
    for n, likely in ((3, False), (5, False)):
        slow = [HAND - [0.3 + 0.03 * i, 0.0, 0.0] for i in range(1, n + 1)]
        pts = [(0.02 * i, np.asarray(p, dtype=float), fine) for i, p in enumerate(hold + slow)]
        fit = eb.early_fit(pts, CFG, PLANE_X, YZ_LO, YZ_HI, G)
        assert fit is not None and fit.n == n
        assert eb.likely_launch(fit, CFG) is likely


def test_without_a_hold_to_leave_there_is_no_early_belief():
    v0 = np.array([-11.0, -0.3, 2.5])
    pts = _points(_flight(v0, 0.02 * np.arange(4)))
    assert eb.flight_run(pts, CFG) == (0, None)
    assert eb.early_fit(pts, CFG, PLANE_X, YZ_LO, YZ_HI, G) is None


def _flight_run_reference(points, cfg):
    """The definition: the longest run of newest points each nearer the plane than the median
    of the points before it by depart_sigmas of its depth noise (at least min_hold before)."""
    n = len(points)
    for k in range(n, 0, -1):
        before = points[: n - k]
        if len(before) < cfg.min_hold:
            continue
        hold = np.median(np.array([p[1] for p in before]), axis=0)
        gap = [cfg.depart_sigmas * np.sqrt(p[2][0, 0]) for p in points[n - k :]]
        if all(hold[0] - p[1][0] > g for p, g in zip(points[n - k :], gap, strict=True)):
            return k, hold
    if n >= cfg.min_hold:
        return 0, np.median(np.array([p[1] for p in points]), axis=0)
    return 0, None


def test_flight_run_is_the_longest_run_that_left_the_median_hold_bit_for_bit():
    rng = np.random.default_rng(7)
    runs = set()
    for _ in range(3000):
        n = int(rng.integers(0, 16))
        flying = int(rng.integers(0, n + 1))
        pts = []
        for i in range(n):
            p = HAND + rng.normal(0.0, 0.05, 3)
            if i >= n - flying:
                p[0] -= rng.uniform(0.0, 1.5)
            s = rng.uniform(0.01, 0.3)
            pts.append((0.02 * i, p, np.diag([s * s, 1e-4, 1e-4])))
        k, hold = eb.flight_run(pts, CFG)
        k_ref, hold_ref = _flight_run_reference(pts, CFG)
        assert k == k_ref
        assert (hold is None and hold_ref is None) or np.array_equal(hold, hold_ref)
        runs.add(k)
    assert len(runs) > 5  # runs of many lengths were met, 0 among them
