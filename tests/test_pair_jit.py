"""The compiled pair kernels (thinkfast.decide.pair_jit) give the numpy reference's values bit
for bit: cut_cells, relative and disk_mean of thinkfast.decide.path_pairs."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.decide.normal_rules import cells, normal_rule
from thinkfast.decide.pair_jit import pair_values, warm_up
from thinkfast.decide.path_pairs import conditional, cut_cells, disk_mean, relative
from thinkfast.decide.shield_paths import BlockGeometry, shield_paths

pytestmark = pytest.mark.usefixtures("compiled_kernels")  # the dispatching calls too

GEOM = BlockGeometry(plane_x=0.8, shield_radius=0.2, half_thickness=0.005, ball_radius=0.0335)


def random_case(rng):
    """Paths that wander across the plane and the touch depth, and a random crossing belief."""
    m, n_t = int(rng.integers(1, 9)), int(rng.integers(1, 40))
    times = 0.3 + np.arange(n_t) * 0.02
    start = rng.normal(0.0, 0.3, size=(m, 1, 3)) + [GEOM.plane_x, 0.0, 1.0]
    steps = rng.normal(0.0, 0.03, size=(m, n_t, 3))
    steps[:, 0] = 0.0
    centre = start + np.cumsum(steps, axis=1)
    centre[..., 0] = (
        GEOM.plane_x
        + rng.uniform(-0.08, 0.03)
        + 0.04 * np.sin(rng.uniform(1.0, 20.0) * times + rng.uniform(0, 6))
    )
    paths = shield_paths(times, centre, GEOM)
    a = rng.normal(size=(3, 3)) * [0.1, 0.1, 0.02]
    cov = a @ a.T + np.diag([1e-4, 1e-4, 1e-5])
    mean = np.array([rng.normal(0.0, 0.2), 1.0 + rng.normal(0.0, 0.2), rng.uniform(0.3, 0.9)])
    b = conditional(mean, cov, 1e-4)
    approach = None if rng.random() < 0.3 else np.array([-rng.uniform(3, 12), *rng.normal(0, 2, 2)])
    ze, we = normal_rule(rng.choice([0.1, 0.5, 5.0, np.inf]), 33, 1.5, 4.5)
    return paths, b, approach, b.sig_e * ze, we


@pytest.mark.parametrize("seed", range(60))
def test_pairs_on_a_node_grid_equal_relative_and_disk_mean_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    paths, b, approach, eta, we = random_case(rng)
    alive = np.flatnonzero(rng.random(paths.n_paths) < 0.8) if paths.n_paths > 1 else [0]
    alive = np.asarray(alive if len(alive) else [0], dtype=np.intp)
    start = rng.normal(0.0, 0.05, size=len(alive))
    zt, _ = normal_rule(rng.choice([0.2, 1.0, 30.0]), 97, 1.5, 4.5)
    rel = relative(paths, alive[:, None], start[:, None], b, zt, GEOM, approach)
    ref = disk_mean(*rel, b, eta, we, GEOM, 5).ravel()
    got = pair_values(paths, alive, start, zt, True, b, GEOM, approach, None, eta, we, 5)
    np.testing.assert_array_equal(got, ref)
    assert got.tobytes() == ref.tobytes()  # signed zeros too


@pytest.mark.parametrize("seed", range(60))
def test_pairs_with_cells_equal_cut_cells_relative_and_disk_mean_bit_for_bit(seed):
    rng = np.random.default_rng(1000 + seed)
    paths, b, approach, eta, we = random_case(rng)
    zt, wt = normal_rule(0.3, 97, 1.5, 4.5, 0.5)
    n = int(rng.integers(1, 4))
    path = np.repeat(rng.integers(0, paths.n_paths, size=n), len(zt))
    start = np.repeat(rng.normal(0.0, 0.05, size=n), len(zt))
    z = np.concatenate((zt,) * n)
    half = np.concatenate((0.5 * b.sd_t * cells(zt, wt),) * n)
    if rng.random() < 0.3:
        half[: len(zt)] = 0.0  # a path of the smooth group: its nodes alone
    z2, share = cut_cells(paths, path, start, b, z, half)
    r_y, r_z, rho, contact = relative(paths, path, start, b, z2, GEOM, approach)
    contact = share if contact is None else contact * share
    ref = disk_mean(r_y, r_z, rho, contact, b, eta, we, GEOM, 5)
    got = pair_values(paths, path, start, z, False, b, GEOM, approach, half, eta, we, 5)
    np.testing.assert_array_equal(got, ref)
    assert got.tobytes() == ref.tobytes()  # signed zeros too


def test_the_cases_reach_every_branch_of_the_reference():
    """The random cases above are not all alike: shields behind the plane and in front, with and
    without lookups, nodes moved to the contact side of a cell."""
    seen = set()
    for seed in range(60):
        rng = np.random.default_rng(1000 + seed)
        paths, b, approach, eta, we = random_case(rng)
        zt, wt = normal_rule(0.3, 97, 1.5, 4.5, 0.5)
        path = np.zeros(len(zt), dtype=np.intp)
        start = np.zeros(len(zt))
        z2, share = cut_cells(paths, path, start, b, zt, 0.5 * b.sd_t * cells(zt, wt))
        rel = relative(paths, path, start, b, z2, GEOM, approach)
        seen.add(("rho", rel[2] is not None))
        seen.add(("moved", bool((z2 != zt).any())))
        seen.add(("approach", approach is not None))
    assert seen >= {("rho", True), ("rho", False), ("moved", True), ("approach", True)}


def test_warm_up_runs_and_a_second_call_is_the_same():
    warm_up()
    warm_up()
