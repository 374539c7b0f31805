"""The action tree in memory: flat numpy arrays (layout in docs/ARCHITECTURE.md).

Nodes are in breadth-first order (depth non-decreasing), node 0 is home at rest, children of a node
are contiguous, terminal edges are sorted by node. Joint-space state of a node: joints 1-3 position
[rad], velocity [rad/s], acceleration [rad/s^2] as ``node_state[:, 0:3]``, ``[3:6]``, ``[6:9]``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

EDGE_CUT = 0  # primitive cut at the maximum duration eps
EDGE_REACHED = 1  # primitive reached its steering target before eps, then held there at rest


@dataclass(frozen=True)
class ActionTree:
    """A compiled action tree.

    Node arrays (N = number of nodes; row i describes node i and the edge into it from its parent,
    row 0 being the root with no incoming edge):
        node_parent (N,) int32: parent node, -1 for the root.
        node_depth (N,) int32: depth, 0 for the root.
        node_ttc (N,) float64: time-to-come from motion start [s].
        node_state (N, 9) float64: joints 1-3 p [rad], v [rad/s], a [rad/s^2].
        node_q (N, 6) float64: all six joints at the node [rad] (wrist by the coplanar rule).
        edge_kind (N,) uint8: EDGE_CUT or EDGE_REACHED (root: EDGE_REACHED).
        edge_duration (N,) float64: duration of the incoming primitive [s] (root: 0).
        edge_target (N,) int32: steering target of the incoming primitive, an index into
            ``subgoal_goal`` (root: -1).
        child_start, child_count (N,) int64: children are ``child_start : child_start + count``.
        term_start, term_count (N,) int64: terminal edges of the node, likewise.
    Terminal arrays (T terminal edges, sorted by node):
        term_node (T,) int32, term_goal (T,) int32 (index into goals),
        term_duration (T,) float64 [s], term_arrival (T,) float64 = ttc(node) + duration [s].
    Goal arrays (G reachable goals, K sub-goals):
        goal_q (G, 6) float64 [rad], goal_yz (G, 2) float64 [m] (base y, z on the plane),
        goal_grid_index (G,) int32: index of the goal in the full IK grid,
        subgoal_goal (K,) int32: goal index of every steering sub-goal.
    grid_yz (M, 2) float64 and grid_reachable (M,) bool: the full IK grid, for reports.
    Shield paths (schema v2; sample spacing ``meta["shield_dt"]`` [s], coplanar normal +x):
        edge_shield (N, E, 3) float64 [m]: shield centre in ``base`` along the edge into node i
            at times 0, dt, ..., eps (E = eps / dt + 1); row 0 (the root's stub) at home.
        term_shield (T, S, 3) float64 [m]: along terminal edge k at times 0, dt, ..., held at
            its goal after the edge's duration (S: the longest terminal edge, rounded up).
    meta: provenance and statistics (plain JSON-able values), written as file attributes.
    """

    node_parent: np.ndarray
    node_depth: np.ndarray
    node_ttc: np.ndarray
    node_state: np.ndarray
    node_q: np.ndarray
    edge_kind: np.ndarray
    edge_duration: np.ndarray
    edge_target: np.ndarray
    child_start: np.ndarray
    child_count: np.ndarray
    term_start: np.ndarray
    term_count: np.ndarray
    term_node: np.ndarray
    term_goal: np.ndarray
    term_duration: np.ndarray
    term_arrival: np.ndarray
    goal_q: np.ndarray
    goal_yz: np.ndarray
    goal_grid_index: np.ndarray
    subgoal_goal: np.ndarray
    grid_yz: np.ndarray
    grid_reachable: np.ndarray
    edge_shield: np.ndarray
    term_shield: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return len(self.node_parent)

    @property
    def n_terminals(self) -> int:
        return len(self.term_node)

    @property
    def max_depth(self) -> int:
        return int(self.node_depth.max()) if self.n_nodes else 0

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array by name (not ``meta``)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "meta"}

    def freeze(self) -> ActionTree:
        """Make every array read-only (in place) and return self."""
        for a in self.arrays().values():
            a.setflags(write=False)
        return self


# dtype of every array, for writers and validating readers
DTYPES: dict[str, np.dtype] = {
    "node_parent": np.dtype(np.int32),
    "node_depth": np.dtype(np.int32),
    "node_ttc": np.dtype(np.float64),
    "node_state": np.dtype(np.float64),
    "node_q": np.dtype(np.float64),
    "edge_kind": np.dtype(np.uint8),
    "edge_duration": np.dtype(np.float64),
    "edge_target": np.dtype(np.int32),
    "child_start": np.dtype(np.int64),
    "child_count": np.dtype(np.int64),
    "term_start": np.dtype(np.int64),
    "term_count": np.dtype(np.int64),
    "term_node": np.dtype(np.int32),
    "term_goal": np.dtype(np.int32),
    "term_duration": np.dtype(np.float64),
    "term_arrival": np.dtype(np.float64),
    "goal_q": np.dtype(np.float64),
    "goal_yz": np.dtype(np.float64),
    "goal_grid_index": np.dtype(np.int32),
    "subgoal_goal": np.dtype(np.int32),
    "grid_yz": np.dtype(np.float64),
    "grid_reachable": np.dtype(np.bool_),
    "edge_shield": np.dtype(np.float64),
    "term_shield": np.dtype(np.float64),
}

# trailing shape of every array (first axis is the count; None: any length, one per file)
SHAPES: dict[str, tuple[int | None, ...]] = {
    "node_state": (9,),
    "node_q": (6,),
    "goal_q": (6,),
    "goal_yz": (2,),
    "grid_yz": (2,),
    "edge_shield": (None, 3),
    "term_shield": (None, 3),
}

UNITS: dict[str, str] = {
    "node_parent": "index",
    "node_depth": "1",
    "node_ttc": "s",
    "node_state": "rad, rad/s, rad/s^2",
    "node_q": "rad",
    "edge_kind": "enum: 0 cut, 1 reached",
    "edge_duration": "s",
    "edge_target": "index into subgoal_goal",
    "child_start": "index",
    "child_count": "1",
    "term_start": "index",
    "term_count": "1",
    "term_node": "index",
    "term_goal": "index into goals",
    "term_duration": "s",
    "term_arrival": "s",
    "goal_q": "rad",
    "goal_yz": "m",
    "goal_grid_index": "index into grid",
    "subgoal_goal": "index into goals",
    "grid_yz": "m",
    "grid_reachable": "bool",
    "edge_shield": "m",
    "term_shield": "m",
}
