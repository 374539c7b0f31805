"""The compiled tree passes (thinkfast.decide.tree_jit) give the numpy code's values: the
terminal values' lookup bit for bit, the backup's maxima equal."""

from __future__ import annotations

import numpy as np
import pytest
from test_backup import random_tree
from test_values import BELIEFS, R, goal_grid

from thinkfast.decide.backup import backup, backup_layout, backup_numpy
from thinkfast.decide.values import (
    ValueConfig,
    layout,
    terminal_values,
    terminal_values_numpy,
)

pytestmark = pytest.mark.usefixtures("compiled_kernels")  # the dispatching calls too


@pytest.mark.parametrize("name", sorted(BELIEFS))
def test_terminal_values_equal_the_numpy_lookup_bit_for_bit(name):
    mean, cov = BELIEFS[name]
    rng = np.random.default_rng(len(name))
    goals = goal_grid()
    term_goal = rng.integers(0, len(goals), 5000)
    remaining = rng.uniform(-0.2, 1.2, 5000)  # before, inside and after the time grid
    lay = layout(goals, term_goal, R, ValueConfig())
    got = terminal_values(lay, mean, cov, remaining)
    ref = terminal_values_numpy(lay, mean, cov, remaining)
    assert got.value.tobytes() == ref.value.tobytes()
    assert got.goal_mass.tobytes() == ref.goal_mass.tobytes()


@pytest.mark.parametrize("seed", range(30))
def test_the_backup_equals_the_level_by_level_numpy_backup(seed):
    rng = np.random.default_rng(seed)
    t = random_tree(rng)
    lay = backup_layout(
        t["node_depth"], t["child_start"], t["child_count"], t["term_start"], t["term_count"]
    )
    n_term = int(np.sum(t["term_count"]))
    tv = rng.random(n_term)
    tv[rng.random(n_term) < 0.3] = 0.0  # ties and zeros, as far beliefs give
    tv[rng.random(n_term) < 0.1] = 1.0
    mass = rng.random(7)
    got, ref = backup(lay, tv, mass), backup_numpy(lay, tv, mass)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)
