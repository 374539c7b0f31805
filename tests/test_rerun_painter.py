"""The Rerun painter's pure geometry: ellipsoids that reproduce a covariance, the crossing flat on
the plane, one line per chosen motion (the painter on a real stream: tests/test_live_view.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thinkfast.daemon.rerun_painter import ellipsoid, matrix_quat, motion_text, plane_cov


def test_the_ellipsoid_reproduces_the_covariance():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.01 * np.eye(3)
    half, quat = ellipsoid(cov, sigmas=2.0)
    r = Rotation.from_quat(quat).as_matrix()
    np.testing.assert_allclose(r @ np.diag((half / 2.0) ** 2) @ r.T, cov, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(matrix_quat(r)).as_matrix(), r, atol=1e-12)


def test_a_degenerate_or_broken_covariance_still_gives_a_finite_ellipsoid():
    half, quat = ellipsoid(np.array([[np.nan, 0, 0], [0, -1e-3, 0], [0, 0, 4.0]]), sigmas=1.0)
    assert np.isfinite(half).all() and np.isfinite(quat).all()
    assert sorted(half) == pytest.approx([0.0, 0.0, 2.0])
    assert np.linalg.norm(quat) == pytest.approx(1.0)


def test_the_crossing_covariance_lies_flat_on_the_plane():
    o_cov = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, 0.003], [0.002, 0.003, 1e-4]])
    c = plane_cov(o_cov, thickness=1e-6)
    assert c[0, 0] == 1e-6 and not c[0, 1:].any() and not c[1:, 0].any()
    np.testing.assert_array_equal(c[1:, 1:], o_cov[:2, :2])


@pytest.mark.parametrize(
    "kind, ref, goal, value, text",
    [
        ("steer", 3, 7, 0.8125, "direct move to goal 7, value 0.812"),
        ("edge", 12, -1, None, "tree branch into node 12"),
        ("terminal", 4, 9, 0.5, "terminal edge 4 to goal 9, value 0.500"),
        ("return", 0, -1, None, "return home"),
        ("wobble", 0, -1, None, "wobble"),
    ],
)
def test_each_motion_is_one_line(kind, ref, goal, value, text):
    assert motion_text(kind, ref, goal, value) == text
