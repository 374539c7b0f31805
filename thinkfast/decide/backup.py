"""QMDP-style backup over the action tree: node values, best child, best terminal, best goal.

``V(node) = max(max over children V(child), max over its terminal edges V(edge))``; a node with
neither has value 0. Terminal values are probabilities (>= 0). The tree arrays follow
``docs/ARCHITECTURE.md``: nodes in breadth-first order (depth non-decreasing), children of a node
contiguous, terminal edges sorted by node. Then the children of all nodes at depth d tile the
nodes at depth d + 1 in order, so one ``np.maximum.reduceat`` per level gives every node's best
child value; every node's best terminal value comes from a precomputed (C, M) gather of its
edges (C = most edges at one node), C element-wise maxima. Ties break towards the lower index.

The arg-max reductions cost several passes each, and the planner needs them only where
execution stands, so :func:`backup` computes values (one reduction per level) and
:func:`best_child` / :func:`best_terminal` answer for one node; :func:`best_children` and
:func:`best_terminals` answer for every node at once.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.robot import kernels


class BackupLayout(NamedTuple):
    """Static reduction plan of a tree (build once with :func:`backup_layout`).

    Attributes:
        levels: deepest first, per depth d >= 1: ``(start, stop, parents, offsets)``: the nodes
            at depth d are ``start:stop``; ``parents`` (P,) are the nodes at depth d - 1 with
            children and ``offsets`` (P,) where their children begin, relative to ``start``.
        term_nodes: nodes with at least one terminal edge, shape (M,).
        term_offsets: where each one's edges begin (the first is 0), shape (M,).
        term_rows: the same edges as a (C, M) gather, the j-th edge of each of those nodes in
            row j and index T (a zero appended to the values) where a node has fewer than C;
            None when that table would be over 3 T (then a segmented reduction is used).
            ``maximum.reduceat`` over thousands of short segments is slow, C row-wise maxima of
            M elements are not.
        child_start, child_count: every node's children, shape (N,) each.
        term_start, term_count: every node's terminal edges, shape (N,) each.
    """

    levels: tuple[tuple[int, int, np.ndarray, np.ndarray], ...]
    term_nodes: np.ndarray
    term_offsets: np.ndarray
    term_rows: np.ndarray | None
    child_start: np.ndarray
    child_count: np.ndarray
    term_start: np.ndarray
    term_count: np.ndarray


class Backup(NamedTuple):
    """Result of :func:`backup`.

    Attributes:
        value: V(node), shape (N,).
        child_value: best value among the node's children (0 if none), shape (N,).
        term_value: best value among the node's own terminal edges (0 if none), shape (N,).
        best_goal: goal whose disk holds the most probability (lowest index on ties), -1 if
            there are no goals: the fallback target when the tree is exhausted.
    """

    value: np.ndarray
    child_value: np.ndarray
    term_value: np.ndarray
    best_goal: int


def backup_layout(
    node_depth: np.ndarray,
    child_start: np.ndarray,
    child_count: np.ndarray,
    term_start: np.ndarray,
    term_count: np.ndarray,
) -> BackupLayout:
    """Plan the level-by-level reductions for a tree in the ARCHITECTURE.md layout.

    Args:
        node_depth: depth of each node, non-decreasing, shape (N,).
        child_start, child_count: contiguous children of each node, shape (N,).
        term_start, term_count: contiguous terminal edges of each node, shape (N,).
    """
    node_depth = np.asarray(node_depth)
    # copies: writable intp arrays, the one type the compiled backup is made for
    child_start = np.array(child_start, dtype=np.intp)
    child_count = np.array(child_count, dtype=np.intp)
    term_start = np.array(term_start, dtype=np.intp)
    term_count = np.array(term_count, dtype=np.intp)
    bounds = np.searchsorted(node_depth, np.arange(int(node_depth.max(initial=0)) + 2))
    levels = []
    for d in range(1, len(bounds) - 1):
        start, stop = int(bounds[d]), int(bounds[d + 1])
        prev = np.arange(bounds[d - 1], bounds[d])
        parents = prev[child_count[prev] > 0]
        levels.append((start, stop, parents, child_start[parents] - start))
    has_term = np.flatnonzero(term_count > 0)
    counts = term_count[has_term]
    width = int(counts.max(initial=0))
    rows = None
    if width * len(has_term) <= 3 * int(counts.sum()):
        j = np.arange(width)[:, None]
        rows = np.where(j < counts, term_start[has_term] + j, int(counts.sum()))
    return BackupLayout(
        levels=tuple(reversed(levels)),
        term_nodes=has_term,
        term_offsets=term_start[has_term],
        term_rows=rows,
        child_start=child_start,
        child_count=child_count,
        term_start=term_start,
        term_count=term_count,
    )


def backup(lay: BackupLayout, term_value: np.ndarray, goal_mass: np.ndarray) -> Backup:
    """Back terminal-edge values up the tree.

    Args:
        lay: plan from :func:`backup_layout`.
        term_value: value of each terminal edge, shape (T,).
        goal_mass: probability mass of each goal's disk, shape (G,).

    Returns:
        A :class:`Backup`.
    """
    if not kernels.compiled():
        return backup_numpy(lay, term_value, goal_mass)
    from thinkfast.decide.tree_jit import backup_values

    value, cv, tv = backup_values(  # compiled: one pass over nodes and edges (tree_jit)
        np.ascontiguousarray(term_value, dtype=float),
        lay.child_start,
        lay.child_count,
        lay.term_start,
        lay.term_count,
    )
    goal = int(np.argmax(goal_mass)) if len(goal_mass) else -1
    return Backup(value, cv, tv, goal)


def backup_numpy(lay: BackupLayout, term_value: np.ndarray, goal_mass: np.ndarray) -> Backup:
    """:func:`backup` in numpy, level by level (the reference of the compiled pass)."""
    n = len(lay.child_count)
    tv = np.zeros(n)
    if lay.term_rows is not None and len(lay.term_nodes):
        ext = np.append(term_value, 0.0)  # values are probabilities: padding with 0 is neutral
        best = ext.take(lay.term_rows[0])
        for row in lay.term_rows[1:]:
            np.maximum(best, ext.take(row), out=best)
        tv[lay.term_nodes] = best
    elif len(lay.term_nodes):
        tv[lay.term_nodes] = np.maximum.reduceat(term_value, lay.term_offsets)
    value = tv.copy()
    cv = np.zeros(n)
    for start, stop, parents, offsets in lay.levels:
        best = np.maximum.reduceat(value[start:stop], offsets)
        cv[parents] = best
        value[parents] = np.maximum(tv[parents], best)
    goal = int(np.argmax(goal_mass)) if len(goal_mass) else -1
    return Backup(value, cv, tv, goal)


def best_child(lay: BackupLayout, value: np.ndarray, node: int) -> int:
    """The node's child with the highest value (lowest index on ties), -1 if it has none."""
    count = int(lay.child_count[node])
    if count == 0:
        return -1
    start = int(lay.child_start[node])
    return start + int(np.argmax(value[start : start + count]))


def best_children(lay: BackupLayout, value: np.ndarray) -> np.ndarray:
    """:func:`best_child` of every node, shape (N,)."""
    out = np.full(len(lay.child_count), -1, dtype=np.intp)
    for start, stop, parents, offsets in lay.levels:
        out[parents] = _first_max(value[start:stop], offsets) + start
    return out


def best_terminal(lay: BackupLayout, term_value: np.ndarray, node: int) -> int:
    """The node's terminal edge with the highest value (lowest index on ties), -1 if none."""
    count = int(lay.term_count[node])
    if count == 0:
        return -1
    start = int(lay.term_start[node])
    return start + int(np.argmax(term_value[start : start + count]))


def best_terminals(lay: BackupLayout, term_value: np.ndarray) -> np.ndarray:
    """:func:`best_terminal` of every node, shape (N,) (one pass over all T edges)."""
    out = np.full(len(lay.term_count), -1, dtype=np.intp)
    if len(lay.term_nodes):
        out[lay.term_nodes] = _first_max(term_value, lay.term_offsets)
    return out


def _first_max(x: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Index of the first maximum of each segment; segments tile ``x`` from ``offsets[0] = 0``."""
    seg_max = np.maximum.reduceat(x, offsets)
    counts = np.diff(np.append(offsets, len(x)))
    hit = np.flatnonzero(x == np.repeat(seg_max, counts))
    return hit[np.searchsorted(hit, offsets)]
