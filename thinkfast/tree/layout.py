"""The tree file's layout as pure checks: groups, datasets, checksums and index invariants.

What :mod:`thinkfast.tree.file` writes and verifies, without HDF5: the dataset of every
:class:`~thinkfast.tree.action_tree.ActionTree` array (``LAYOUT``), the groups they sit in and
their row counts (``GROUPS``), the checksum of an array, and :func:`layout_problem`, the
invariants the runtime relies on (``docs/TREE_FORMAT.md``). A tree's fingerprint, over its arrays
and its identity attributes, is :mod:`thinkfast.tree.identity`'s.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from thinkfast.tree.action_tree import DTYPES, EDGE_CUT, EDGE_REACHED, FIELDS, SHAPES

SHIELD_DT = "shield_dt"  # meta key (v2, required): sample spacing of the shield paths [s]

# group -> (row count symbol, doc); every dataset of a group has the same first-axis length
GROUPS: dict[str, tuple[str, str]] = {
    "nodes": ("N", "one row per node, breadth-first order, row 0 the root (home at rest)"),
    "edges": ("N", "row i: the primitive into node i from its parent; row 0 is the root's stub"),
    "terminals": ("T", "one row per terminal edge (full primitive to a goal, at rest), by node"),
    "goals": ("G", "one row per reachable goal of the IK grid"),
    "subgoals": ("K", "one row per steering sub-goal"),
    "grid": ("M", "one row per point of the full IK goal grid on the plane"),
}

# (ActionTree array, dataset path, doc) in fingerprint order: from the one field table
LAYOUT: tuple[tuple[str, str, str], ...] = tuple((f.name, f.path, f.doc) for f in FIELDS)
PATHS = {name: path for name, path, _ in LAYOUT}

# derived convenience datasets, written and checked but not part of the ActionTree
DERIVED: tuple[tuple[str, str, str], ...] = (
    ("/edges/parent", "index", "node the primitive leaves from (= /nodes/parent)"),
    ("/edges/child", "index", "node the primitive ends at (= row index)"),
)


def array_sha256(a: np.ndarray) -> str:
    """Checksum of an array: sha256 of ``"<dtype>:<shape>\\n"`` then its little-endian bytes.

    Args:
        a: any array; it is hashed in C order with little-endian byte order, e.g. the header of
            a float64 array of shape (5, 9) is ``"<f8:5,9\\n"`` (bool: ``"|b1"``).

    Returns:
        64 hex digits.
    """
    le = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
    h = hashlib.sha256(f"{le.dtype.str}:{','.join(map(str, le.shape))}\n".encode("ascii"))
    h.update(le.reshape(-1).view(np.uint8).data)
    return h.hexdigest()


def layout_problem(arrays: Mapping[str, np.ndarray]) -> str | None:
    """First violation of the in-memory layout, or None for a valid tree.

    Checks dtypes, shapes, equal row counts per group, and the index invariants the runtime relies
    on: root first, parents before children, depth non-decreasing, contiguous in-bounds child and
    terminal ranges matching the parent and node columns, indices within their targets.

    Args:
        arrays: every ActionTree array by name (as from :meth:`ActionTree.arrays`).
    """
    for name, path, _ in LAYOUT:
        a = arrays[name]
        if a.dtype.newbyteorder("<") != DTYPES[name].newbyteorder("<"):
            return f"{path} has dtype {a.dtype}, expected {DTYPES[name]}"
        want = SHAPES.get(name, ())
        fits = all(w is None or w == d for w, d in zip(want, a.shape[1:], strict=False))
        if a.ndim != 1 + len(want) or not fits:
            sym = GROUPS[path.split("/")[1]][0]
            shown = ", ".join([sym, *("S" if w is None else str(w) for w in want)])
            return f"{path} has shape {a.shape}, expected ({shown})"
    counts: dict[str, tuple[int, str]] = {}
    for name, path, _ in LAYOUT:
        group = path.split("/")[1]
        n, first = counts.setdefault(group, (len(arrays[name]), path))
        if len(arrays[name]) != n:
            return f"{path} has {len(arrays[name])} rows but {first} has {n}"
    for name in ("edge_shield", "term_shield"):
        if not np.all(np.isfinite(arrays[name])):
            return f"{PATHS[name]} holds a value that is not finite"
    if arrays["edge_shield"].shape[1] < 1:
        return f"{PATHS['edge_shield']} has no samples"
    return _index_problem(arrays)


def shield_dt_problem(meta: Mapping[str, Any]) -> str | None:
    """The v2 meta key ``shield_dt`` must be a positive finite float."""
    dt = meta.get(SHIELD_DT)
    if isinstance(dt, bool) or not isinstance(dt, int | float) or not 0.0 < dt < np.inf:
        return f"meta {SHIELD_DT} (sample spacing of the shield paths, s) is {dt!r}: need > 0"
    return None


def _index_problem(a: Mapping[str, np.ndarray]) -> str | None:
    """First violation of the index invariants (root, parents, depths, ranges, targets)."""
    parent, depth = a["node_parent"], a["node_depth"]
    n, t, g = len(parent), len(a["term_node"]), len(a["goal_yz"])
    k, m = len(a["subgoal_goal"]), len(a["grid_yz"])
    if n == 0:
        return "no root node (/nodes is empty)"
    if parent[0] != -1 or depth[0] != 0:
        return "row 0 is not a root (/nodes/parent[0] must be -1, /nodes/depth[0] 0)"
    rows = np.arange(n)
    bad = np.flatnonzero((parent[1:] < 0) | (parent[1:] >= rows[1:])) + 1
    if bad.size:
        return f"/nodes/parent[{bad[0]}] = {parent[bad[0]]} is not in 0..{bad[0] - 1}"
    if np.any(np.diff(depth) < 0):
        return f"/nodes/depth decreases at row {np.flatnonzero(np.diff(depth) < 0)[0] + 1}"
    bad = np.flatnonzero(depth[1:] != depth[parent[1:]] + 1) + 1
    if bad.size:
        return f"/nodes/depth[{bad[0]}] is not its parent's depth + 1"
    problem = _range_problem("child", a["child_start"], a["child_count"], parent[1:], 1, n)
    if problem:
        return problem
    if np.any(np.diff(a["term_node"]) < 0):
        return "/terminals/node is not sorted (non-decreasing)"
    if t and (a["term_node"].min() < 0 or a["term_node"].max() >= n):
        return f"/terminals/node holds an index outside 0..{n - 1}"
    problem = _range_problem("term", a["term_start"], a["term_count"], a["term_node"], 0, t)
    if problem:
        return problem
    if not np.all(np.isin(a["edge_kind"], (EDGE_CUT, EDGE_REACHED))):
        return f"/edges/kind holds a value other than {EDGE_CUT} (cut) or {EDGE_REACHED} (reached)"
    for name, lo, hi in (
        ("edge_target", -1, k),
        ("term_goal", 0, g),
        ("subgoal_goal", 0, g),
        ("goal_grid_index", 0, m),
    ):
        v = a[name]
        if v.size and (v.min() < lo or v.max() >= hi):
            return f"{PATHS[name]} holds an index outside {lo}..{hi - 1}"
    return None


def _range_problem(
    kind: str, start: np.ndarray, count: np.ndarray, owner: np.ndarray, first: int, total: int
) -> str | None:
    """Rows ``first + j`` belong to node ``owner[j]``; each node's range must hold exactly them."""
    label = f"/nodes/{kind}_start, /nodes/{kind}_count"
    if np.any((start < 0) | (start > total) | (count < 0) | (count > total - start)):
        return f"{label}: a range is outside 0..{total}"
    if not np.array_equal(np.bincount(owner, minlength=len(start)), count):
        return f"{label}: counts do not match the rows that name the node"
    rows = np.arange(first, first + len(owner))
    own = owner.astype(np.intp)
    bad = np.flatnonzero((rows < start[own]) | (rows >= start[own] + count[own]))
    if bad.size:
        return f"{label}: row {rows[bad[0]]} lies outside the range of node {owner[bad[0]]}"
    return None
