"""Shield IK (thinkfast.robot.ik): its LAPACK solve without numpy's wrapper."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.robot.ik import _solve


def test_solve_equals_np_linalg_solve_bit_for_bit_on_damped_normal_equations():
    """The Levenberg-Marquardt systems (J^T J + lam D) dq = -J^T r of random Jacobians."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        J = rng.normal(size=(6, 5)) * 10.0 ** rng.uniform(-3, 1)
        H = J.T @ J
        a = H + 10.0 ** rng.uniform(-9, 3) * np.diag(np.diag(H) + 1e-9)
        b = -J.T @ rng.normal(size=6)
        assert np.array_equal(_solve(a, b), np.linalg.solve(a, b))


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_a_singular_system_raises_as_np_linalg_solve_does():
    with pytest.raises(np.linalg.LinAlgError):
        _solve(np.ones((5, 5)), np.ones(5))
