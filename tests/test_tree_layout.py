"""The tree layout without HDF5: array checksums and every index invariant, each violation named
(the file round trips: tests/test_treefile.py; fingerprints: tests/test_tree_checksums.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.treegen import random_tree
from thinkfast.tree.layout import array_sha256, layout_problem, shield_dt_problem


def test_checksum_covers_bytes_dtype_and_shape_but_not_byte_order():
    a = np.arange(6, dtype=np.float64)
    assert array_sha256(a) == array_sha256(a.astype(">f8"))
    assert array_sha256(a) != array_sha256(a.reshape(2, 3))
    assert array_sha256(a) != array_sha256(a.view(np.int64))
    assert array_sha256(a[::2]) == array_sha256(a[::2].copy())


def test_treegen_trees_satisfy_the_layout_invariants():
    for seed in range(40):
        tree = random_tree(seed, max_depth=1 + seed % 4, max_children=1 + seed % 3)
        assert layout_problem(tree.arrays()) is None, seed
        assert np.array_equal(tree.term_arrival, tree.node_ttc[tree.term_node] + tree.term_duration)


def _broken(change):
    arrays = dict(random_tree(2, max_depth=3, max_children=2).arrays())
    change(arrays)
    return layout_problem(arrays)


def _put(arrays, name, i, value):
    a = arrays[name].copy()
    a[i] = value
    arrays[name] = a


@pytest.mark.parametrize(
    "change, needle",
    [
        (lambda a: a.update(node_parent=a["node_parent"].astype(np.int64)), "dtype int64"),
        (lambda a: a.update(node_state=a["node_state"][:, :8]), "expected (N, 9)"),
        (lambda a: a.update(goal_q=a["goal_q"][:-1]), "rows but /goals/"),
        (lambda a: _put(a, "node_parent", 0, 0), "row 0 is not a root"),
        (lambda a: _put(a, "node_parent", 2, 2), "/nodes/parent[2] = 2 is not in 0..1"),
        (lambda a: _put(a, "child_count", 0, 99), "a range is outside"),
        (lambda a: _put(a, "term_goal", 0, 10**6), "/terminals/goal holds an index"),
        (lambda a: _put(a, "edge_kind", 1, 7), "/edges/kind holds a value other"),
        (lambda a: _put(a, "edge_shield", 1, np.inf), "/edges/shield holds a value"),
    ],
)
def test_each_layout_violation_is_named(change, needle):
    problem = _broken(change)
    assert problem is not None and needle in problem


@pytest.mark.parametrize("value", [None, 0.0, -0.02, float("inf"), True, "0.02"])
def test_a_shield_spacing_that_is_no_positive_number_is_a_problem(value):
    assert "shield_dt" in shield_dt_problem({"shield_dt": value})
    assert shield_dt_problem({"shield_dt": 0.02}) is None
