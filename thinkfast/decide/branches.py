"""Compiled branches as motion options: every continuation below a node, from the tree file's
shield paths (schema v2), packed once for the path-value kernel.

A *continuation* is a path from the root to a terminal edge: the tree edges into each ancestor of
the terminal's node (the edge into depth d runs over ``[(d - 1) eps, d eps]`` of the path's clock,
which reads 0 at the virtual motion start), then the terminal edge from ``ttc(node)``, held at its
goal after. A compiled edge into child c of node n is worth the best continuation through c
(the paper's max-backup, with the judge's moving-shield value instead of arrival at rest). Only
continuations below the root are packed: the root's own terminal edges are the direct moves from
home, which the chooser computes anyway.

The arm can take child c's edge only from n's state: at home at rest (n the root), or at the end
of the edge into n that it follows. The caller gives the path clock's origin (wall time at which
the path clock reads 0, ``t_switch - ttc(n)``), shifted by the controller lag, as ``t_start``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.decide.path_value import PathValueConfig, block_probability
from thinkfast.decide.shield_paths import BlockGeometry, shield_paths
from thinkfast.tree.action_tree import ActionTree


class BranchValues(NamedTuple):
    """Values of the child edges of one node.

    Attributes:
        child: child nodes that have a scored continuation, shape (C,).
        value: best continuation's P(block) through each, shape (C,).
        goal: that continuation's goal, shape (C,).
    """

    child: np.ndarray
    value: np.ndarray
    goal: np.ndarray


def continuation_paths(tree: ActionTree, rows: np.ndarray) -> np.ndarray:
    """Shield centres [m] of the continuations ending with terminal edges ``rows`` (R,), on the
    path clock every ``shield_dt`` from 0, held at the goal after arrival, shape (R, L, 3)."""
    steps = tree.edge_shield.shape[1] - 1
    node = tree.term_node[rows]
    depth = tree.node_depth[node].astype(np.intp)
    s = tree.term_shield.shape[1]
    length = int(depth.max(initial=0)) * steps + s
    out = np.empty((len(rows), length, 3))
    cur = node.astype(np.intp)
    for d in range(int(depth.max(initial=0)), 0, -1):  # the edge into depth d, from the leaf up
        on = depth >= d
        lo = (d - 1) * steps
        out[on, lo : lo + steps + 1] = tree.edge_shield[cur[on]]
        cur[on] = tree.node_parent[cur[on]]
    out[depth == 0, 0] = tree.edge_shield[0, 0]
    for d in np.unique(depth).tolist():
        on = np.flatnonzero(depth == d)
        lo = d * steps
        out[on, lo : lo + s] = tree.term_shield[rows[on]]
        out[on, lo + s :] = tree.term_shield[rows[on], -1][:, None]
    return out


class BranchTable:
    """Every continuation below the root, packed, and for every node the continuations through
    each of its children (see the module doc).

    To bound the work per belief, each (node, child, goal) keeps only its ``per_goal`` earliest
    arriving continuations (the ones that leave the most time; ties by row).

    Args:
        tree: a compiled tree (schema v2, with shield paths).
        geom: plane, shield and ball.
        per_goal: continuations kept per node, child edge and goal (0: all).
    """

    def __init__(self, tree: ActionTree, geom: BlockGeometry, per_goal: int = 1):
        self.tree, self.geom = tree, geom
        self.dt = float(tree.meta["shield_dt"])
        depth_n = tree.node_depth
        rows = np.flatnonzero(depth_n[tree.term_node] >= 1)
        self.rows = rows
        self.goal = tree.term_goal[rows].astype(np.intp)
        self.packed = None
        if len(rows):
            paths = continuation_paths(tree, rows)
            self.packed = shield_paths(np.arange(paths.shape[1]) * self.dt, paths, geom)
        # (node, packed row, child) for every ancestor node of every continuation's terminal
        depth = depth_n[tree.term_node[rows]].astype(np.intp)
        anc = np.full((len(rows), int(depth.max(initial=0)) + 1), -1, dtype=np.intp)
        cur, d = tree.term_node[rows].astype(np.intp), depth.copy()
        for _ in range(anc.shape[1]):
            ok = d >= 0
            anc[np.flatnonzero(ok), d[ok]] = cur[ok]
            cur = np.where(ok, tree.node_parent[np.maximum(cur, 0)], -1)
            d -= 1
        owner, member, child = [], [], []
        for k in range(anc.shape[1] - 1):
            on = np.flatnonzero(depth > k)
            owner.append(anc[on, k])
            member.append(on)
            child.append(anc[on, k + 1])
        owner_a = np.concatenate(owner) if owner else np.zeros(0, np.intp)
        member_a = np.concatenate(member) if member else np.zeros(0, np.intp)
        child_a = np.concatenate(child) if child else np.zeros(0, np.intp)
        arrival = tree.term_arrival[rows][member_a]
        order = np.lexsort((member_a, arrival, self.goal[member_a], child_a, owner_a))
        if per_goal > 0 and len(order):  # rank within each (owner, child, goal), earliest first
            key = np.stack([owner_a, child_a, self.goal[member_a]], axis=1)[order]
            new = np.r_[True, np.any(key[1:] != key[:-1], axis=1)]
            first = np.flatnonzero(new)
            rank = np.arange(len(order)) - np.repeat(first, np.diff(np.r_[first, len(order)]))
            order = order[rank < per_goal]
        owner_a, self.member, self.child = owner_a[order], member_a[order], child_a[order]
        count = np.bincount(owner_a, minlength=tree.n_nodes)
        self.start = np.r_[0, np.cumsum(count)[:-1]]
        self.count = count

    def through(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        """Packed rows of the continuations below ``node`` and the child each passes through."""
        a, n = int(self.start[node]), int(self.count[node])
        return self.member[a : a + n], self.child[a : a + n]

    def values(
        self,
        node: int,
        goals: np.ndarray,
        mean: np.ndarray,
        cov: np.ndarray,
        approach: np.ndarray | None,
        t_start: float,
        cfg: PathValueConfig = PathValueConfig(),
    ) -> BranchValues:
        """Best continuation value through every child of ``node`` among the continuations that
        end at one of ``goals`` (indices).

        Args:
            mean, cov: crossing belief N(Y, Z, tau), tau from the belief's time.
            approach: mean ball velocity at the crossing [m/s] (3,) or None.
            t_start: when the path clock reads 0, plus the controller lag, from the belief's
                time [s] (the node is reached at ``t_start + ttc(node)``).
        """
        member, child = self.through(node)
        keep = np.isin(self.goal[member], goals)
        member, child = member[keep], child[keep]
        if member.size == 0 or self.packed is None:
            empty = np.zeros(0, dtype=np.intp)
            return BranchValues(empty, np.zeros(0), empty)
        v = block_probability(self.packed, mean, cov, self.geom, approach, t_start, cfg, member)
        kids, inverse = np.unique(child, return_inverse=True)
        best = np.full(len(kids), -1.0)
        np.maximum.at(best, inverse, v)
        # the continuation that gives each child its value (first in packed order on ties)
        order = np.lexsort((member, -v, inverse))
        first = order[np.r_[0, np.flatnonzero(np.diff(inverse[order])) + 1]]
        return BranchValues(kids, best, self.goal[member[first]])
