"""Backup over the action tree (thinkfast.decide.backup) against a brute-force recursion."""

from __future__ import annotations

import numpy as np

from thinkfast.decide.backup import (
    backup,
    backup_layout,
    best_child,
    best_children,
    best_terminal,
    best_terminals,
)


def random_tree(rng, max_depth=4, max_children=5, max_terms=4, p_leafy=0.3):
    """A random tree in the ARCHITECTURE.md layout: BFS nodes, contiguous children, terminal
    edges sorted by node. Any node may have children, terminals, both or neither."""
    depth, parent = [0], [-1]
    child_start, child_count = [], []
    frontier, d = [0], 0
    while frontier:
        nxt = []
        for node in frontier:
            k = (
                0
                if d >= max_depth or rng.random() < p_leafy
                else int(rng.integers(0, max_children))
            )
            child_start.append(len(depth))
            child_count.append(k)
            for _ in range(k):
                nxt.append(len(depth))
                depth.append(d + 1)
                parent.append(node)
        frontier, d = nxt, d + 1
    n = len(depth)
    term_count = rng.integers(0, max_terms + 1, n)
    term_start = np.concatenate([[0], np.cumsum(term_count)[:-1]])
    return dict(
        node_parent=np.array(parent),
        node_depth=np.array(depth),
        child_start=np.array(child_start),
        child_count=np.array(child_count),
        term_start=term_start,
        term_count=term_count,
        term_node=np.repeat(np.arange(n), term_count),
    )


def reference(tree, tv):
    """Brute-force recursive V(node), best child and best terminal (lowest index on ties)."""
    n = len(tree["node_depth"])
    value, best_child, best_term = np.zeros(n), np.full(n, -1), np.full(n, -1)

    def visit(i):
        cands = []
        s, c = tree["child_start"][i], tree["child_count"][i]
        child_vals = [visit(j) for j in range(s, s + c)]
        if c:
            m = max(child_vals)
            best_child[i] = s + child_vals.index(m)
            cands.append(m)
        s, c = tree["term_start"][i], tree["term_count"][i]
        if c:
            vals = list(tv[s : s + c])
            best_term[i] = s + vals.index(max(vals))
            cands.append(max(vals))
        value[i] = max(cands, default=0.0)
        return value[i]

    visit(0)
    return value, best_child, best_term


def layout_of(tree):
    return backup_layout(
        tree["node_depth"],
        tree["child_start"],
        tree["child_count"],
        tree["term_start"],
        tree["term_count"],
    )


def test_backup_matches_brute_force_recursion_on_random_trees_with_ties():
    rng = np.random.default_rng(0)
    for trial in range(300):
        tree = random_tree(rng, max_depth=int(rng.integers(0, 6)))
        n_terms = int(tree["term_count"].sum())
        # coarse values make ties frequent; some trials are all-zero (no crossing)
        tv = np.round(rng.uniform(0, 1, n_terms), 1) if trial % 10 else np.zeros(n_terms)
        goal_mass = np.round(rng.uniform(0, 1, 7), 1)
        lay = layout_of(tree)
        got = backup(lay, tv, goal_mass)
        segmented = backup(lay._replace(term_rows=None), tv, goal_mass)  # the other code path
        np.testing.assert_array_equal(segmented.value, got.value)
        value, best_child_ref, best_term = reference(tree, tv)
        np.testing.assert_array_equal(got.value, value)
        np.testing.assert_array_equal(best_children(lay, got.value), best_child_ref)
        np.testing.assert_array_equal(best_terminals(lay, tv), best_term)
        for node in range(len(value)):
            assert best_child(lay, got.value, node) == best_child_ref[node]
            assert best_terminal(lay, tv, node) == best_term[node]
        has_child = best_child_ref >= 0
        np.testing.assert_array_equal(got.child_value[has_child], value[best_child_ref[has_child]])
        np.testing.assert_array_equal(got.child_value[~has_child], 0.0)
        has_term = best_term >= 0
        np.testing.assert_array_equal(got.term_value[has_term], tv[best_term[has_term]])
        assert got.best_goal == int(np.flatnonzero(goal_mass == goal_mass.max())[0])


def test_single_node_tree_and_empty_goal_set():
    tree = dict(
        node_depth=np.array([0]),
        child_start=np.array([1]),
        child_count=np.array([0]),
        term_start=np.array([0]),
        term_count=np.array([0]),
    )
    got = backup(layout_of(tree), np.zeros(0), np.zeros(0))
    assert got.value[0] == 0.0 and got.best_goal == -1
    assert best_child(layout_of(tree), got.value, 0) == -1
    assert best_terminal(layout_of(tree), np.zeros(0), 0) == -1


def test_value_is_zero_where_nothing_hangs_below():
    tree = dict(
        node_depth=np.array([0, 1, 1]),
        child_start=np.array([1, 3, 3]),
        child_count=np.array([2, 0, 0]),
        term_start=np.array([0, 0, 2]),
        term_count=np.array([0, 2, 0]),
    )
    got = backup(layout_of(tree), np.array([0.3, 0.7]), np.array([0.1]))
    np.testing.assert_array_equal(got.value, [0.7, 0.7, 0.0])
    np.testing.assert_array_equal(best_children(layout_of(tree), got.value), [1, -1, -1])
