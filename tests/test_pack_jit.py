"""The compiled packing (thinkfast.decide.pack_jit, behind shield_paths.pack) equals the numpy
packing bit for bit, touch-depth crossings and their overflow included."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.decide.shield_paths import MAX_CUTS, BlockGeometry, pack, pack_numpy

pytestmark = pytest.mark.usefixtures("compiled_kernels")  # the dispatching calls too

GEOM = BlockGeometry(plane_x=0.8, shield_radius=0.2, half_thickness=0.005, ball_radius=0.0335)


@pytest.mark.parametrize("seed", range(40))
def test_packing_equals_the_numpy_packing_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    m, n_t = int(rng.integers(1, 12)), int(rng.integers(1, 60))
    times = rng.uniform(-0.5, 0.5) + np.arange(n_t) * rng.uniform(0.002, 0.05)
    planes = np.empty((6, m * n_t))
    planes[:3] = rng.normal(0.0, 0.2, size=(3, m * n_t)) + [[0.75], [0.0], [1.0]]
    # x crossing the touch depth often: more crossings than kept on some paths
    planes[0] = GEOM.touch_x + rng.normal(0.0, 0.02, size=m * n_t)
    ref, got = pack_numpy(times, planes.copy(), GEOM), pack(times, planes, GEOM)
    assert got._fields == ref._fields
    for name, a, b in zip(ref._fields, ref, got, strict=True):
        if isinstance(a, np.ndarray):
            assert a.shape == b.shape and a.dtype == b.dtype, name
            np.testing.assert_array_equal(b, a, err_msg=name)
            assert b.tobytes() == a.tobytes(), name  # signed zeros too
        else:
            assert a == b, name
    if n_t > 3 * MAX_CUTS:
        assert (got.cuts[:, 0] == -np.inf).any()
