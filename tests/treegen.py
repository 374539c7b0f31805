"""Small synthetic but valid action trees for file-format and inspection tests (seeded).

The trees honour every layout invariant of :mod:`thinkfast.tree.action_tree`: breadth-first nodes,
contiguous children, terminal edges sorted by node (leaving from the deepest level only, like the
compiler), ``child ttc = parent ttc + edge duration`` and ``arrival = ttc(node) + duration``.
Their numbers are random, not physical; shield paths are sampled every ``SHIELD_DT`` (tree edges:
random points near the plane; terminal edges: straight to their goal's point, then held).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib

import numpy as np

from thinkfast.compile.config import CompileConfig
from thinkfast.config import from_dict, to_dict
from thinkfast.tree.action_tree import EDGE_CUT, EDGE_REACHED, ActionTree

SHIELD_DT = 0.02  # s

CONFIG_TEMPLATE = """\
robot = "../robots/irb1600/robot.toml"

[plane]
distance = 0.8

[goals]
spacing = {spacing}

[tree]
max_depth = {max_depth}
eps = {eps}
connect_radius = 0.3
"""


def random_tree(
    seed: int = 0,
    *,
    max_depth: int = 3,
    max_children: int = 3,
    spacing: float = 0.3,
    eps: float = 0.1,
    reachable: float = 0.8,
    terminals_per_leaf: int = 4,
) -> ActionTree:
    """A random valid tree.

    Args:
        seed: random seed; the same arguments give the same tree.
        max_depth: depth of the deepest nodes (>= 1); terminal edges leave from them.
        max_children: each node above ``max_depth`` gets 1..max_children children.
        spacing: goal grid step on the plane y -0.9..0.9, z 0.25..1.75 [m].
        eps: maximum primitive duration [s]; cut edges last exactly eps.
        reachable: fraction of grid points that become goals.
        terminals_per_leaf: up to this many terminal edges per deepest node (distinct goals).
    """
    rng = np.random.default_rng(seed)
    ys = np.arange(-0.9, 0.9 + 1e-9, spacing)
    zs = np.arange(0.25, 1.75 + 1e-9, spacing)
    grid_yz = np.array([(y, z) for z in zs for y in ys], dtype=np.float64).reshape(-1, 2)
    grid_reachable = rng.random(len(grid_yz)) < reachable
    grid_reachable[0] = True
    goal_grid_index = np.flatnonzero(grid_reachable).astype(np.int32)
    g = len(goal_grid_index)
    subgoal_goal = np.sort(rng.choice(g, size=min(g, 6), replace=False)).astype(np.int32)

    parent, depth, kind, duration, target = [-1], [0], [EDGE_REACHED], [0.0], [-1]
    child_start, child_count = [], []
    i = 0
    while i < len(parent):
        n_children = 0 if depth[i] == max_depth else int(rng.integers(1, max_children + 1))
        child_start.append(len(parent))
        child_count.append(n_children)
        for _ in range(n_children):
            cut = bool(rng.random() < 0.7)
            parent.append(i)
            depth.append(depth[i] + 1)
            kind.append(EDGE_CUT if cut else EDGE_REACHED)
            duration.append(eps if cut else float(rng.uniform(0.2, 0.95) * eps))
            target.append(int(rng.integers(len(subgoal_goal))))
        i += 1
    n = len(parent)
    node_parent = np.array(parent, dtype=np.int32)
    edge_duration = np.array(duration, dtype=np.float64)
    node_ttc = np.zeros(n)
    for j in range(1, n):
        node_ttc[j] = node_ttc[node_parent[j]] + edge_duration[j]

    leaves = np.flatnonzero(np.array(depth) == max_depth)
    term_node, term_goal = [], []
    for leaf in leaves:
        k = int(rng.integers(0, terminals_per_leaf + 1))
        for goal in np.sort(rng.choice(g, size=min(k, g), replace=False)):
            term_node.append(leaf)
            term_goal.append(goal)
    term_duration = rng.uniform(0.1, 0.6, size=len(term_node))

    tree = ActionTree(
        node_parent=node_parent,
        node_depth=np.array(depth, dtype=np.int32),
        node_ttc=node_ttc,
        node_state=rng.normal(size=(n, 9)),
        node_q=rng.uniform(-2.0, 2.0, size=(n, 6)),
        edge_kind=np.array(kind, dtype=np.uint8),
        edge_duration=edge_duration,
        edge_target=np.array(target, dtype=np.int32),
        child_start=np.array(child_start, dtype=np.int64),
        child_count=np.array(child_count, dtype=np.int64),
        term_start=np.zeros(n, dtype=np.int64),
        term_count=np.zeros(n, dtype=np.int64),
        term_node=np.zeros(0, dtype=np.int32),
        term_goal=np.zeros(0, dtype=np.int32),
        term_duration=np.zeros(0),
        term_arrival=np.zeros(0),
        goal_q=rng.uniform(-2.0, 2.0, size=(g, 6)),
        goal_yz=grid_yz[goal_grid_index].copy(),
        goal_grid_index=goal_grid_index,
        subgoal_goal=subgoal_goal,
        grid_yz=grid_yz,
        grid_reachable=grid_reachable,
        edge_shield=0.8 + 0.3 * rng.normal(size=(n, round(eps / SHIELD_DT) + 1, 3)),
        term_shield=np.zeros((0, 1, 3)),
        meta=sample_meta(max_depth=max_depth, eps=eps, spacing=spacing),
    )
    return with_terminals(tree, np.array(term_node), np.array(term_goal), term_duration)


MACHINE = {
    "cpu": "Test CPU 9000",
    "cores": 2,
    "machine": "x86_64",
    "system": "Linux",
    "blas": {"name": "scipy-openblas", "version": "0.3.31", "architecture": "Haswell"},
    "numpy_simd": {"baseline": ["X86_V2"], "found": ["X86_V3"]},
    "env": {},
}


def sample_meta(**params: float) -> dict:
    """Provenance and statistics like the compiler writes, around a TOML config text."""
    text = CONFIG_TEMPLATE.format(**params)
    return {
        "created": "2025-01-01T00:00:00Z",
        "thinkfast_version": "0.1.0",
        "ruckig_version": "0.19.4",
        "pinocchio_version": "3.4.0",
        "numpy_version": "2.4.6",
        "machine": MACHINE,
        "config_text": text,
        "config_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "urdf_sha256": hashlib.sha256(b"urdf").hexdigest(),
        "robot_toml_sha256": hashlib.sha256(b"robot.toml").hexdigest(),
        "robot_name": "irb1600",
        "parameters": resolved(text),
        "plane_distance": 0.8,
        "shield_radius": 0.2,
        "jobs": 2,
        "seconds": 1.5,
        "discards": {"position_limit": 3, "collision": 5},
        "shield_dt": SHIELD_DT,
    }


def resolved(text: str) -> str:
    """The resolved parameters of a compile config text, as the compiler writes them (JSON)."""
    return json.dumps(to_dict(from_dict(CompileConfig, tomllib.loads(text), "treegen")))


def with_terminals(
    tree: ActionTree, term_node: np.ndarray, term_goal: np.ndarray, term_duration: np.ndarray
) -> ActionTree:
    """The tree with new terminal edges (sorted by node, then goal); ranges and arrivals rebuilt."""
    order = np.lexsort((term_goal, term_node))
    node = np.asarray(term_node, dtype=np.int32)[order]
    duration = np.asarray(term_duration, dtype=np.float64)[order]
    count = np.bincount(node, minlength=tree.n_nodes).astype(np.int64)
    goal = np.asarray(term_goal, dtype=np.int32)[order]
    return dataclasses.replace(
        tree,
        term_node=node,
        term_goal=goal,
        term_shield=terminal_shield(tree.goal_yz[goal], duration),
        term_duration=duration,
        term_arrival=tree.node_ttc[node] + duration,
        term_start=(np.cumsum(count) - count).astype(np.int64),
        term_count=count,
    )


def with_config(tree: ActionTree, old: str, new: str) -> ActionTree:
    """The tree with ``old`` replaced by ``new`` in its config text and the parameters resolved
    again from it (arrays unchanged)."""
    text = tree.meta["config_text"].replace(old, new)
    assert text != tree.meta["config_text"], old
    sha = hashlib.sha256(text.encode()).hexdigest()
    meta = dict(tree.meta, config_text=text, config_sha256=sha, parameters=resolved(text))
    return dataclasses.replace(tree, meta=meta)


def terminal_shield(goal_yz: np.ndarray, duration: np.ndarray) -> np.ndarray:
    """Synthetic terminal shield paths (T, S, 3): from (0.7, 0, 1) straight to (0.8, goal y, z)
    over the edge's duration, held there, sampled every ``SHIELD_DT`` [s]."""
    s = int(np.ceil(duration.max() / SHIELD_DT - 1e-9)) + 1 if len(duration) else 1
    u = np.clip(np.arange(s)[None, :] * SHIELD_DT / np.maximum(duration[:, None], 1e-9), 0, 1)
    start, end = np.array([0.7, 0.0, 1.0]), np.c_[np.full(len(goal_yz), 0.8), goal_yz]
    return start + u[:, :, None] * (end[:, None, :] - start)


def resign(path) -> None:
    """Write the checksum table of a tree file again over what it now holds, as the writer would:
    a test's edit then reaches the checks behind the table (layout, JSON, fingerprint)."""
    import h5py

    from thinkfast.tree.manifest import TABLE, entries_of, plain, table_text

    with h5py.File(path, "r+") as f:
        root = {k: plain(v) for k, v in f.attrs.items() if k != TABLE}
        groups: dict = {}
        datasets: dict = {}

        def visit(_, obj) -> None:
            attrs = {k: plain(v) for k, v in obj.attrs.items()}
            if isinstance(obj, h5py.Dataset):
                datasets[obj.name] = (np.asarray(obj[()]), attrs)
            else:
                groups[obj.name] = attrs

        f.visititems(visit)
        f.attrs[TABLE] = table_text(entries_of(root, groups, datasets))
