"""thinkfast.estimate.linalg.inv: np.linalg.inv's results bit for bit, its error when singular."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.estimate.linalg import clip, inv


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


def test_clip_equals_maximum_then_minimum_in_place():
    """The same values (a -0.0 stays -0.0 where np.maximum makes it 0.0: equal values; the
    kernels never produce a -0.0 there, as x - y is +0.0 when x == y)."""
    rng = np.random.default_rng(7)
    x = rng.normal(size=1000) * 10.0 ** rng.uniform(-3, 3, 1000)
    x[:3] = [0.0, -0.0, 5.0]
    want = np.minimum(np.maximum(x, 0.0), 5.0)
    out = x.copy()
    assert clip(out, 0.0, 5.0, out=out) is out
    assert np.array_equal(out, want)
    differ = np.signbit(out) != np.signbit(want)
    assert np.array_equal(np.flatnonzero(differ), [1])  # the -0.0 alone
