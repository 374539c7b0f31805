"""thinkfast.estimate.linalg.inv: np.linalg.inv's results bit for bit, its error when singular."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.estimate.linalg import inv


@pytest.mark.parametrize("n", [2, 3, 6])
def test_inverse_equals_np_linalg_inv_bit_for_bit_on_random_spd_stacks(n):
    rng = np.random.default_rng(n)
    for _ in range(200):
        a = rng.normal(size=(4, n, n)) * 10.0 ** rng.uniform(-4, 3)
        spd = a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(n)
        assert np.array_equal(inv(spd), np.linalg.inv(spd))
        assert np.array_equal(inv(spd[0]), np.linalg.inv(spd[0]))


@pytest.mark.filterwarnings("ignore:invalid value encountered in inv:RuntimeWarning")
def test_a_singular_matrix_raises_as_np_linalg_inv_does():
    with pytest.raises(np.linalg.LinAlgError):
        inv(np.ones((3, 3)))
