"""Fixed-order small linear algebra (thinkfast.robot.fixed_order), and what it is for: the same
compiled tree under every BLAS kernel."""

from __future__ import annotations

import math
import os
import platform
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from thinkfast.robot import fixed_order as fo

ROBOT = os.path.join(os.path.dirname(__file__), "..", "robots", "irb1600", "robot.toml")


def _in_order(a, b):
    """Sums of products over the inner index written out one term at a time."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            s = a[i, 0] * b[0, j]
            for k in range(1, a.shape[1]):
                s = s + a[i, k] * b[k, j]
            out[i, j] = s
    return out


def test_matmul_sums_the_inner_index_in_order_and_broadcasts_as_matmul():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(7, 3, 3)), rng.normal(size=(7, 3, 4))
    got = fo.matmul(a, b)
    assert got.shape == (7, 3, 4)
    for n in range(7):
        assert np.array_equal(got[n], _in_order(a[n], b[n]))
    np.testing.assert_allclose(got, a @ b, rtol=0, atol=1e-14)
    pts, R = rng.normal(size=(5, 3)), rng.normal(size=(9, 3, 3))
    assert fo.matmul(pts, R).shape == (9, 5, 3)
    np.testing.assert_allclose(fo.matmul(pts, R), pts @ R, rtol=0, atol=1e-14)
    v = rng.normal(size=3)
    np.testing.assert_allclose(fo.matmul(R, v), R @ v, rtol=0, atol=1e-14)
    np.testing.assert_allclose(fo.matmul(v, R), v @ R, rtol=0, atol=1e-14)


def test_matvec_dot_and_norm_agree_with_numpy_and_with_the_written_out_sums():
    rng = np.random.default_rng(2)
    a, v = rng.normal(size=(4, 6, 5)), rng.normal(size=(4, 5))
    got = fo.matvec(a, v)
    for n in range(4):
        assert np.array_equal(got[n], _in_order(a[n], v[n][:, None])[:, 0])
    x = rng.normal(size=(10, 3))
    d = fo.dot(x, x)
    assert np.array_equal(d, (x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1]) + x[:, 2] * x[:, 2])
    np.testing.assert_allclose(fo.norm(x), np.linalg.norm(x, axis=1), rtol=1e-15)
    assert float(fo.norm(np.array([3.0, 4.0]))) == 5.0


def test_solve_solves_the_damped_normal_equations_of_the_ik():
    """The Levenberg-Marquardt systems (J^T J + lam D) dq = -J^T r of random Jacobians."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        J = rng.normal(size=(6, 5)) * 10.0 ** rng.uniform(-3, 1)
        H = J.T @ J
        a = H + 10.0 ** rng.uniform(-6, 3) * np.diag(np.diag(H) + 1e-9)
        b = -J.T @ rng.normal(size=6)
        x = fo.solve(a, b)
        assert np.linalg.norm(a @ x - b) <= 1e-9 * (np.linalg.norm(a) * np.linalg.norm(x) + 1e-300)


def test_solve_pivots_and_refuses_a_singular_system():
    x = fo.solve(np.array([[0.0, 1.0], [1.0, 0.0]]), np.array([2.0, 3.0]))
    assert np.array_equal(x, [3.0, 2.0])
    with pytest.raises(np.linalg.LinAlgError):
        fo.solve(np.ones((5, 5)), np.ones(5))


# Kernels every x86-64 that numpy supports can run (numpy's baseline is SSE4.2), and that sum in
# other orders than the newer ones: before the fixed-order products each gave its own tree.
KERNELS = ("Nehalem", "Prescott")

CONFIG = """\
robot = "{robot}"
[plane]
distance = 0.8
[goals]
spacing = 0.3
[tree]
max_depth = 2
"""

COMPILE = textwrap.dedent(
    """
    import sys
    from thinkfast.compile.build import compile_tree
    from thinkfast.compile.config import load_compile_config
    from thinkfast.tree.identity import tree_fingerprint
    tree = compile_tree(load_compile_config(sys.argv[1]))
    print(tree_fingerprint(tree), len(tree.term_node))
    """
)


def _compile_under(
    kernel: str | None, config: str, numpy_off: str | None = None
) -> tuple[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")
    }
    if numpy_off:
        env["NPY_DISABLE_CPU_FEATURES"] = numpy_off
    env["OPENBLAS_VERBOSE"] = "2"  # OpenBLAS names the kernel it loaded on stderr
    if kernel:
        env["OPENBLAS_CORETYPE"] = kernel
    done = subprocess.run(
        [sys.executable, "-c", COMPILE, config], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip(), done.stderr


def _core(log: str) -> str:
    lines = [line for line in log.splitlines() if line.startswith("Core:")]
    assert lines, f"OpenBLAS named no kernel: {log[-300:]}"
    return lines[0]


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="x86-64 kernel names")
def test_a_small_tree_has_one_fingerprint_under_every_blas_kernel(tmp_path):
    config = tmp_path / "small.toml"
    config.write_text(CONFIG.format(robot=os.path.abspath(ROBOT)))
    own, log = _compile_under(None, str(config))
    for kernel in KERNELS:
        got, other = _compile_under(kernel, str(config))
        assert _core(other) != _core(log), f"OPENBLAS_CORETYPE={kernel} changed no kernel"
        assert got == own, f"OPENBLAS_CORETYPE={kernel}: {got} against {own} ({_core(log)})"


def _numpy_vector_paths() -> list[str]:
    """numpy's run-time dispatched CPU features that this CPU has (X86_V3, X86_V4, ...)."""
    from numpy._core import _multiarray_umath as um

    return [f for f in um.__cpu_dispatch__ if um.__cpu_features__.get(f)]


def test_arccos_and_arctan2_are_the_c_librarys_bit_for_bit():
    rng = np.random.default_rng(3)
    u, x = rng.uniform(-1.0, 1.0, 4000), rng.uniform(-3.0, 3.0, 4000)
    acos = fo.arccos(u.reshape(40, 100))
    assert acos.shape == (40, 100)
    assert acos.ravel().tolist() == [math.acos(v) for v in u.tolist()]
    atan = fo.arctan2(x, u[:1])  # broadcasts as np.arctan2
    assert atan.shape == x.shape
    assert atan.tolist() == [math.atan2(a, u[0]) for a in x.tolist()]
    assert np.allclose(acos.ravel(), np.arccos(u), rtol=0, atol=1e-15)


@pytest.mark.skipif(not _numpy_vector_paths(), reason="numpy dispatches no vector code here")
def test_a_small_tree_has_one_fingerprint_with_numpys_vector_code_on_and_off(tmp_path):
    """numpy's AVX-512 arccos and arctan2 (SVML) differ from the C library's in the last bit;
    the wrist angles of the tree came out different on such a CPU before fixed_order took
    them from the C library."""
    config = tmp_path / "small.toml"
    config.write_text(CONFIG.format(robot=os.path.abspath(ROBOT)))
    own, _ = _compile_under(None, str(config))
    off = ",".join(_numpy_vector_paths())
    got, _ = _compile_under(None, str(config), numpy_off=off)
    assert got == own, f"NPY_DISABLE_CPU_FEATURES={off}: {got} against {own}"
