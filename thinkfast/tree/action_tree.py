"""The action tree in memory: flat numpy arrays (layout in docs/ARCHITECTURE.md).

Nodes are in breadth-first order (depth non-decreasing), node 0 is home at rest, children of a node
are contiguous, terminal edges are sorted by node. Joint-space state of a node: joints 1-3 position
[rad], velocity [rad/s], acceleration [rad/s^2] as ``node_state[:, 0:3]``, ``[3:6]``, ``[6:9]``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, NamedTuple

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


class Field(NamedTuple):
    """One array of the tree: the single source of its name, file path, dtype, shape, unit and
    doc (the writer, the validating reader, the fingerprint order and docs/TREE_FORMAT.md follow
    from :data:`FIELDS`; tests/test_treefile.py checks the document)."""

    name: str  # ActionTree attribute
    path: str  # HDF5 dataset
    dtype: type  # numpy scalar type
    trailing: tuple  # shape after the row axis (None: any length, one per file)
    rows: str  # N nodes, T terminal edges, G goals, K sub-goals, M grid points
    unit: str
    doc: str


# every array, in fingerprint order
FIELDS: tuple[Field, ...] = (
    Field("node_parent", "/nodes/parent", np.int32, (), "N", "index",
          "parent node, -1 for the root; below the node's own index"),
    Field("node_depth", "/nodes/depth", np.int32, (), "N", "1",
          "depth, 0 for the root; non-decreasing along rows"),
    Field("node_ttc", "/nodes/ttc", np.float64, (), "N", "s",
          "time-to-come: time from motion start to reach the node"),
    Field("node_state", "/nodes/state", np.float64, (9,), "N", "rad, rad/s, rad/s^2",
          "joints 1-3 position (cols 0:3), velocity (3:6), accel (6:9)"),
    Field("node_q", "/nodes/q", np.float64, (6,), "N", "rad",
          "all six joint angles at the node (wrist by the coplanar rule)"),
    Field("child_start", "/nodes/child_start", np.int64, (), "N", "index",
          "children are rows child_start : child_start + count"),
    Field("child_count", "/nodes/child_count", np.int64, (), "N", "1",
          "number of children"),
    Field("term_start", "/nodes/term_start", np.int64, (), "N", "index",
          "terminal edges are rows term_start : term_start + count"),
    Field("term_count", "/nodes/term_count", np.int64, (), "N", "1",
          "number of terminal edges leaving the node"),
    Field("edge_kind", "/edges/kind", np.uint8, (), "N", "enum: 0 cut, 1 reached",
          "0: cut at the maximum duration eps, 1: reached its target"),
    Field("edge_duration", "/edges/duration", np.float64, (), "N", "s",
          "duration of the primitive into the node (root: 0)"),
    Field("edge_target", "/edges/target", np.int32, (), "N", "index into subgoal_goal",
          "steering target, a row of /subgoals (root: -1)"),
    Field("term_node", "/terminals/node", np.int32, (), "T", "index",
          "node the terminal edge leaves from (non-decreasing)"),
    Field("term_goal", "/terminals/goal", np.int32, (), "T", "index into goals",
          "goal the terminal edge ends at, at rest (row of /goals)"),
    Field("term_duration", "/terminals/duration", np.float64, (), "T", "s",
          "duration of the terminal primitive"),
    Field("term_arrival", "/terminals/arrival", np.float64, (), "T", "s",
          "arrival time at the goal from motion start: ttc + dur"),
    Field("goal_q", "/goals/q", np.float64, (6,), "G", "rad",
          "six joint angles at the goal (IK solution)"),
    Field("goal_yz", "/goals/yz", np.float64, (2,), "G", "m",
          "goal position on the intercept plane (base y, base z)"),
    Field("goal_grid_index", "/goals/grid_index", np.int32, (), "G", "index into grid",
          "row of the goal in /grid"),
    Field("subgoal_goal", "/subgoals/goal", np.int32, (), "K", "index into goals",
          "goal (row of /goals) of every steering sub-goal"),
    Field("grid_yz", "/grid/yz", np.float64, (2,), "M", "m",
          "grid point on the intercept plane (base y, base z)"),
    Field("grid_reachable", "/grid/reachable", np.bool_, (), "M", "bool",
          "the IK solved the point (it is then one of /goals)"),
    Field("edge_shield", "/edges/shield", np.float64, (None, 3), "N", "m",
          "shield centre (base x, y, z) along the edge every shield_dt"),
    Field("term_shield", "/terminals/shield", np.float64, (None, 3), "T", "m",
          "shield centre along the edge every shield_dt, then held"),
)  # fmt: skip

DTYPES: dict[str, np.dtype] = {f.name: np.dtype(f.dtype) for f in FIELDS}
SHAPES: dict[str, tuple[int | None, ...]] = {f.name: f.trailing for f in FIELDS if f.trailing}
UNITS: dict[str, str] = {f.name: f.unit for f in FIELDS}
