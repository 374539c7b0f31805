"""P(block) of moving shields (thinkfast.decide.path_value) against Monte Carlo, today's static
values, the judge's geometry, and its own invariants."""

from __future__ import annotations

import math
import warnings
import zlib

import numpy as np
import pytest
from path_mc import belief, judge_block, model_block
from scipy.special import ndtr

from thinkfast.control.segments import Steering
from thinkfast.decide.normal_rules import normal_rule
from thinkfast.decide.path_value import PathValueConfig, block_probability
from thinkfast.decide.shield_paths import BlockGeometry, shield_paths
from thinkfast.decide.values import ValueConfig, layout, terminal_values
from thinkfast.estimate.crossing import crossing

GEOM = BlockGeometry(plane_x=0.8, shield_radius=0.2, half_thickness=0.005, ball_radius=0.0335)
RHO = GEOM.shield_radius + GEOM.ball_radius
TIMES = np.arange(0.0, 1.2 + 1e-9, 0.01)
V_MAX = 3.0  # m/s, about the fastest shield of the default tree (bench/path_value.py)


def random_belief(rng, sd_t=(0.003, 0.06), v_shield=V_MAX):
    """A crossing Gaussian inside the kernel's accuracy domain: the tau rate sd_t (v + |k|) at
    most 9 sigma_a, the lateral anisotropy of (Y, Z) | tau at most 3 (real throws: 10, 2.3)."""
    st = 10 ** rng.uniform(*np.log10(sd_t))
    k = rng.normal(size=2)
    k *= rng.uniform(0.0, 4.0) / np.linalg.norm(k)
    sig_a = max(10 ** rng.uniform(-2.0, -0.7), st * (v_shield + np.linalg.norm(k)) / 9.0)
    mean = [rng.uniform(-0.4, 0.4), rng.uniform(0.6, 1.4), rng.uniform(0.3, 0.6)]
    return belief(mean, sig_a, rng.uniform(1.0, 3.0), rng.uniform(0, np.pi), st, k)


def on_plane(yz):
    return np.column_stack([np.full(len(yz), GEOM.plane_x), yz])


def unit(rng):
    u = rng.normal(size=2)
    return u / np.linalg.norm(u)


def sweep(rng, mean, cov, speed):
    """A shield crossing the belief's mean point at ``speed`` near the mean crossing time."""
    t_pass = mean[2] + rng.uniform(-2, 2) * math.sqrt(cov[2, 2])
    p = mean[:2] + unit(rng) * rng.uniform(0.0, 0.15)
    return on_plane(p + np.outer(TIMES - t_pass, unit(rng) * speed))


def arrival(rng, mean, cov, sigmas):
    """A shield coming at 1-3 m/s from 0.5-0.9 m away to rest near the mean crossing point; its
    edge (shield + ball radius from the centre) reaches that point ``sigmas`` tau-sigmas after
    the mean crossing time."""
    goal = mean[:2] + unit(rng) * rng.uniform(0.0, 0.1)
    src = goal + unit(rng) * rng.uniform(0.5, 0.9)
    speed = rng.uniform(1.0, 3.0)
    dur = np.linalg.norm(src - goal) / speed
    t_arr = mean[2] + sigmas * math.sqrt(cov[2, 2]) + RHO / speed
    return on_plane(goal + np.outer(np.clip((t_arr - TIMES) / dur, 0.0, 1.0), src - goal))


def case(kind, rng, robot):
    """(times, centres (T, 3), mean, cov, approach, t_start, geometry) of one seeded case."""
    approach = np.array([-rng.uniform(8, 15), rng.uniform(-1, 1), rng.uniform(-4, 3)])
    if kind == "static":
        mean, cov = random_belief(rng)
        p = mean[:2] + unit(rng) * rng.uniform(0.0, RHO + 0.1)
        return TIMES[:1], on_plane(p[None]), mean, cov, None, 0.0, GEOM
    if kind in ("sweep_slow", "sweep_fast"):
        mean, cov = random_belief(rng)
        c = sweep(rng, mean, cov, 0.5 if kind == "sweep_slow" else V_MAX)
        return TIMES, c, mean, cov, None, 0.0, GEOM
    if kind in ("arrive_before", "arrive_after"):
        mean, cov = random_belief(rng)
        s = rng.uniform(0.3, 2.0) * (-1 if kind == "arrive_before" else 1)
        return TIMES, arrival(rng, mean, cov, s), mean, cov, approach, 0.0, GEOM
    if kind in ("narrow_tau", "wide_tau"):
        mean, cov = random_belief(rng, (0.002, 0.004) if kind == "narrow_tau" else (0.06, 0.1))
        c = sweep(rng, mean, cov, 1.5) if rng.random() < 0.5 else arrival(rng, mean, cov, 0.5)
        return TIMES, c, mean, cov, approach, 0.0, GEOM
    if kind == "off_plane":  # in front, behind, through the touch depth
        mean, cov = random_belief(rng)
        c = sweep(rng, mean, cov, 1.0)
        c[:, 0] += rng.uniform(-0.06, 0.15) + (TIMES - mean[2]) * rng.uniform(-0.6, 0.6)
        return TIMES, c, mean, cov, approach, 0.0, GEOM
    if kind == "joint_move":  # a Ruckig move of joints 1-3 from home, shield by FK
        from thinkfast.robot.shield_path import ShieldSampler, sample_joint_paths

        steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
        traj = steer.to_rest(
            np.r_[robot.home[:3], np.zeros(6)], robot.home[:3] + rng.uniform(-0.5, 0.5, 3)
        )
        c = ShieldSampler(robot).centres(sample_joint_paths([traj], TIMES))[0]
        mean, cov = random_belief(rng)
        mean[:2] = c[-1, 1:] + unit(rng) * rng.uniform(0.0, 0.2)
        t_start = mean[2] - traj.duration + rng.uniform(-1.5, 1.5) * math.sqrt(cov[2, 2])
        geom = GEOM._replace(plane_x=float(c[-1, 0]) + rng.uniform(-0.02, 0.02))
        return TIMES, c, mean, cov, approach, t_start, geom
    if kind == "delta_method":  # a filter-like belief early in a throw, a shield arriving
        state = np.array([5.8, 0.1, 1.6, -12.0, 0.4, 2.5])
        s_cov = np.diag([0.08, 0.01, 0.01, 1.5, 0.2, 0.2]) ** 2
        s_cov[0, 3] = s_cov[3, 0] = 0.6 * 0.08 * 1.5
        cr = crossing(state, s_cov, GEOM.plane_x, 9.81)
        v = state[3:] - [0.0, 0.0, 9.81 * cr.mean[2]]
        return (
            TIMES,
            arrival(rng, cr.mean, cr.cov, rng.uniform(-1.5, 1.5)),
            cr.mean,
            cr.cov,
            v,
            0.0,
            GEOM,
        )
    raise ValueError(kind)


KINDS = ("static", "sweep_slow", "sweep_fast", "arrive_before", "arrive_after", "narrow_tau",
         "wide_tau", "off_plane", "joint_move", "delta_method")  # fmt: skip


@pytest.mark.parametrize("kind", KINDS)
def test_block_probability_matches_a_monte_carlo_of_the_model_within_0005(kind, robot):
    """Four seeded cases per kind; the Monte Carlo samples the same geometric model directly
    (exact meeting time, no quadrature, no tables), 250,000 samples: its sd is at most 1e-3.
    Most cases are uncertain (neither 0 nor 1), so the comparison means something."""
    rng = np.random.default_rng(zlib.crc32(kind.encode()))
    mc = np.random.default_rng(zlib.crc32(kind.encode()) + 1)  # the cases do not hang on it
    uncertain = 0
    for _ in range(4):
        times, c, mean, cov, approach, t_start, geom = case(kind, rng, robot)
        paths = shield_paths(times, c, geom)
        got = block_probability(paths, mean, cov, geom, approach, t_start)[0]
        ref = model_block(times, c, mean, cov, geom, approach, t_start, 250_000, mc)
        assert abs(got - ref) <= 0.005, (kind, got, ref)
        uncertain += 0.02 < ref < 0.98
    assert uncertain >= 2


def test_a_shield_at_rest_blocks_with_the_disk_mass_of_todays_values():
    """Static shields on the plane: the disk mass of thinkfast.decide.shield_disk (via values)
    within 5e-4, for beliefs from 5 mm to 0.5 m, correlated with tau or not."""
    rng = np.random.default_rng(3)
    for _ in range(40):
        mean, cov = random_belief(rng, v_shield=0.0)
        goals = mean[:2] + np.array([unit(rng) * r for r in rng.uniform(0, RHO + 0.15, 6)])
        paths = shield_paths(TIMES[:1], on_plane(goals)[:, None, :], GEOM)
        got = block_probability(paths, mean, cov, GEOM)
        lay = layout(goals, np.arange(6), RHO, ValueConfig())
        ref = terminal_values(lay, mean, cov, np.full(6, -10.0)).goal_mass
        assert np.max(np.abs(got - ref)) <= 5e-4


def test_a_shield_that_appears_at_its_goal_at_t_gets_todays_terminal_value():
    """A kilometre behind the plane until t, then at rest at the goal (t a sample: the touch depth
    is crossed 0.4 us before t): today's value P(disk, tau > t) with no margin (values.py is
    itself within 0.0025 of Monte Carlo)."""
    rng = np.random.default_rng(4)
    for _ in range(12):
        mean, cov = random_belief(rng, v_shield=0.0)
        goal = mean[:2] + unit(rng) * rng.uniform(0, RHO)
        t_arr = mean[2] + rng.uniform(-2, 2) * math.sqrt(cov[2, 2])
        times = t_arr + np.arange(-100, 101) * 0.01
        c = on_plane(np.tile(goal, (len(times), 1)))
        c[:100, 0] -= 1000.0  # no contact before t_arr
        got = block_probability(shield_paths(times, c, GEOM), mean, cov, GEOM)[0]
        lay = layout(goal[None], [0], RHO, ValueConfig(margin=0.0))
        ref = terminal_values(lay, mean, cov, np.array([t_arr])).value[0]
        assert abs(got - ref) <= 0.005


def test_the_geometry_is_the_judges_within_its_sampling_noise():
    """Against the simulator's sphere-cylinder judge along straight flights (20,000 samples, sd
    <= 0.0035): shields in front, on and behind the plane, moving or not, within 0.012."""
    rng = np.random.default_rng(5)
    for dx in (0.2, 0.05, 0.0, -0.015, -0.03, -0.05):
        mean, cov = belief([0.0, 1.0, 0.5], 0.08, 1.3, 0.4, 0.02, [0.5, -1.0])
        c = sweep(rng, mean, cov, rng.uniform(0.0, 2.0))
        c[:, 0] += dx + (TIMES - 0.5) * rng.uniform(-0.3, 0.3)
        approach = np.array([-rng.uniform(9, 13), rng.uniform(-1, 1), rng.uniform(-4, 2)])
        got = block_probability(shield_paths(TIMES, c, GEOM), mean, cov, GEOM, approach)[0]
        ref = judge_block(TIMES, c, mean, cov, GEOM, approach, 0.0, 20_000, rng)
        assert abs(got - ref) <= 0.012, (dx, got, ref)


def test_starting_later_is_the_same_path_shifted_in_time():
    """t_start per path is a shift of its clock: exact for one shift of all paths; per path it
    equals separate calls within the quadrature tolerance (nodes are chosen per call)."""
    rng = np.random.default_rng(6)
    mean, cov = random_belief(rng)
    c = np.stack([arrival(rng, mean, cov, s) for s in (-1.0, 0.0, 1.0)])
    a = block_probability(shield_paths(TIMES, c, GEOM), mean, cov, GEOM, None, 0.07)
    b = block_probability(shield_paths(TIMES + 0.07, c, GEOM), mean, cov, GEOM)
    assert np.allclose(a, b, atol=1e-12) and np.ptp(a) > 0.1
    shift = np.array([0.05, -0.1, 0.2])
    a = block_probability(shield_paths(TIMES, c, GEOM), mean, cov, GEOM, None, shift)
    b = [block_probability(shield_paths(TIMES + d, ci, GEOM), mean, cov, GEOM)[0]
         for d, ci in zip(shift, c, strict=True)]  # fmt: skip
    assert np.allclose(a, b, atol=2e-4)


def test_an_index_scores_a_subset_with_its_own_starts():
    rng = np.random.default_rng(9)
    mean, cov = random_belief(rng)
    c = np.stack([arrival(rng, mean, cov, s) for s in (-1.0, 0.0, 1.0, 2.0)])
    paths = shield_paths(TIMES, c, GEOM)
    start = np.array([0.0, 0.02, -0.03, 0.1])
    full = block_probability(paths, mean, cov, GEOM, None, start)
    sub = block_probability(paths, mean, cov, GEOM, None, start[[3, 1]], index=np.array([3, 1]))
    assert sub.shape == (2,) and np.allclose(sub, full[[3, 1]], atol=2e-4)


def test_probabilities_are_bounded_and_a_shield_out_of_reach_blocks_nothing():
    rng = np.random.default_rng(7)
    for _ in range(20):
        mean, cov = random_belief(rng)
        c = np.stack([sweep(rng, mean, cov, 2.0), arrival(rng, mean, cov, 0.0)])
        far = on_plane(np.tile(mean[:2] + [3.0, 0.0], (len(TIMES), 1)))
        behind = c[1] - [0.1, 0.0, 0.0]  # 10 cm behind the plane: no touch
        p = block_probability(
            shield_paths(TIMES, np.stack([*c, far, behind]), GEOM), mean, cov, GEOM
        )
        assert np.all(p >= 0.0) and np.all(p <= 1.0 + 1e-9)
        assert p[2] == 0.0 and p[3] == 0.0


def test_degenerate_beliefs_give_finite_values_without_warnings():
    rising = on_plane(np.tile([0.1, 1.1], (len(TIMES), 1)))
    rising[:, 0] += np.clip(TIMES - 0.45, -0.1, 0.0)  # through the touch depth at 0.4 s
    c = np.stack(
        [
            on_plane(np.tile([0.1, 1.1], (len(TIMES), 1))),
            arrival(np.random.default_rng(8), np.array([0.1, 1.1, 0.4]), np.eye(3) * 1e-4, 0.0),
            rising,
        ]
    )
    paths = shield_paths(TIMES, c, GEOM)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for cov in (np.zeros((3, 3)), np.diag([0.0, 0.01, 1e-4]), np.eye(3) * 1e-20,
                    np.full((3, 3), 0.01), np.diag([0.01, 0.01, 1e-4])):  # fmt: skip
            p = block_probability(
                paths, np.array([0.1, 1.1, 0.4]), cov, GEOM, np.array([-10.0, 0, 0])
            )
            assert np.all(np.isfinite(p)) and np.all(p <= 1.0 + 1e-9)


@pytest.mark.parametrize("scale", [0.05, 0.2, 0.5, 0.9, 1.0, 1.5, 3.0, 6.0, 30.0])
def test_node_rules_integrate_a_blurred_step_of_their_scale_to_2e4(scale):
    """The rule table's claim: E[Phi((Z - z0) / s)] exact is Phi(-z0 / sqrt(1 + s^2))."""
    cfg = PathValueConfig()
    x, w = normal_rule(scale, 10_000, 1.25, 5.5)
    z0 = np.linspace(-4, 4, 161)
    got = ndtr((x[None, :] - z0[:, None]) / scale) @ w
    assert np.max(np.abs(got - ndtr(-z0 / math.sqrt(1 + scale * scale)))) < 2e-4
    x, w = normal_rule(scale, 10_000, cfg.step_ratio, cfg.k_sigma)
    got = ndtr((x[None, :] - z0[:, None]) / scale) @ w
    assert np.max(np.abs(got - ndtr(-z0 / math.sqrt(1 + scale * scale)))) < 1e-3


def test_node_counts_stay_within_the_caps_for_any_belief():
    cfg = PathValueConfig()
    for scale in (1e-9, 1e-3, 0.01):
        assert len(normal_rule(scale, cfg.max_time_nodes, cfg.step_ratio, cfg.k_sigma)[0]) <= 97
        assert len(normal_rule(scale, cfg.max_lateral_nodes, 1.5, 4.5, 0.5)[0]) <= 33


def test_paths_need_a_uniform_increasing_grid_and_matching_shapes():
    c = on_plane(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="uniform"):
        shield_paths(np.array([0.0, 0.1, 0.3, 0.4, 0.5]), c, GEOM)
    with pytest.raises(ValueError, match="need times"):
        shield_paths(np.arange(4) * 0.1, c, GEOM)
    with pytest.raises(ValueError, match="finite"):
        shield_paths(np.arange(5) * 0.1, c * np.nan, GEOM)
