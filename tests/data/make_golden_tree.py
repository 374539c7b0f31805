"""Write the golden tree file of the current schema version (``tests/data/tree_v3_golden.h5``).

Run once per schema version and commit the output; never regenerate a released version's golden
file (it is what old files look like). ``tests/test_treefile.py`` checks its known values (and
that ``tree_v1_golden.h5`` and ``tree_v2_golden.h5``, written by this script before v2 added the
shield paths and before v3 added the checksum table, are refused with the fix named).

    python tests/data/make_golden_tree.py [OUT] [--force]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tomllib
from pathlib import Path

import numpy as np

from thinkfast.compile.config import CompileConfig
from thinkfast.config import from_dict, to_dict
from thinkfast.tree.action_tree import EDGE_CUT, EDGE_REACHED, ActionTree
from thinkfast.tree.file import SCHEMA_VERSION, save_tree

CONFIG_TEXT = """\
robot = "../robots/irb1600/robot.toml"

[plane]
distance = 0.8

[tree]
max_depth = 2
eps = 0.1
"""


def golden_tree() -> ActionTree:
    """Root, two children, one grandchild each; the grandchildren reach three goals."""
    ttc = np.array([0.0, 0.1, 0.1, 0.2, 0.2])
    term_node = np.array([3, 3, 4, 4], dtype=np.int32)
    term_duration = np.array([0.3, 0.25, 0.2, 0.35])
    grid_yz = np.array([[-0.15, 0.85], [0.0, 1.0], [0.15, 1.0], [0.15, 0.85]])
    # shield centres every 0.05 s: edges of 0.1 s (3 samples), terminals up to 0.35 s (8)
    edge_shield = np.array([[[0.6, 0.0, 1.0]] * 3] + [
        [[0.6, 0.0, 1.0], [0.65, 0.05 * i, 1.0], [0.7, 0.1 * i, 1.0]] for i in range(1, 5)
    ])  # fmt: skip
    u = np.clip(np.arange(8)[None, :] * 0.05 / term_duration[:, None], 0.0, 1.0)
    end = np.c_[np.full(4, 0.8), grid_yz[[0, 1, 1, 3]]]
    term_shield = np.array([0.7, 0.0, 1.0]) + u[:, :, None] * (end[:, None] - [0.7, 0.0, 1.0])
    return ActionTree(
        node_parent=np.array([-1, 0, 0, 1, 2], dtype=np.int32),
        node_depth=np.array([0, 1, 1, 2, 2], dtype=np.int32),
        node_ttc=ttc,
        node_state=np.arange(45, dtype=np.float64).reshape(5, 9) / 100.0,
        node_q=np.arange(30, dtype=np.float64).reshape(5, 6) / 10.0 - 1.0,
        edge_kind=np.array([EDGE_REACHED, EDGE_CUT, EDGE_CUT, EDGE_CUT, EDGE_REACHED], np.uint8),
        edge_duration=np.array([0.0, 0.1, 0.1, 0.1, 0.1]),
        edge_target=np.array([-1, 0, 1, 1, 0], dtype=np.int32),
        child_start=np.array([1, 3, 4, 5, 5], dtype=np.int64),
        child_count=np.array([2, 1, 1, 0, 0], dtype=np.int64),
        term_start=np.array([0, 0, 0, 0, 2], dtype=np.int64),
        term_count=np.array([0, 0, 0, 2, 2], dtype=np.int64),
        term_node=term_node,
        term_goal=np.array([0, 1, 1, 2], dtype=np.int32),
        term_duration=term_duration,
        term_arrival=ttc[term_node] + term_duration,
        goal_q=np.array(
            [
                [0.1, 0.2, 0.3, 0.0, 0.4, 0.0],
                [0.0, 0.1, 0.2, 0.0, 0.3, 0.0],
                [-0.1, 0.2, 0.3, 0.0, 0.4, 0.0],
            ]
        ),
        goal_yz=grid_yz[[0, 1, 3]],
        goal_grid_index=np.array([0, 1, 3], dtype=np.int32),
        subgoal_goal=np.array([0, 2], dtype=np.int32),
        grid_yz=grid_yz,
        grid_reachable=np.array([True, True, False, True]),
        edge_shield=edge_shield,
        term_shield=term_shield,
        meta={
            "created": "2025-01-01T00:00:00Z",
            "thinkfast_version": "0.1.0",
            "ruckig_version": "0.19.4",
            "pinocchio_version": "3.4.0",
            "numpy_version": "2.4.6",
            "machine": {"cpu": "Golden CPU", "blas": {"name": "openblas", "architecture": "Zen"}},
            "config_path": "/golden/tree.toml",
            "config_text": CONFIG_TEXT,
            "config_sha256": hashlib.sha256(CONFIG_TEXT.encode()).hexdigest(),
            "urdf_sha256": hashlib.sha256(b"golden urdf").hexdigest(),
            "robot_toml_sha256": hashlib.sha256(b"golden robot.toml").hexdigest(),
            "robot_name": "golden",
            "parameters": json.dumps(
                to_dict(from_dict(CompileConfig, tomllib.loads(CONFIG_TEXT), "golden"))
            ),
            "plane_distance": 0.8,
            "shield_radius": 0.2,
            "jobs": 1,
            "seconds": 0.25,
            "deterministic": True,
            "discards": {"position_limit": 2, "collision": 1},
            "shield_dt": 0.05,
        },
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "out",
        nargs="?",
        default=str(Path(__file__).with_name(f"tree_v{SCHEMA_VERSION}_golden.h5")),
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    args = parser.parse_args(argv)
    if Path(args.out).exists() and not args.force:
        print(f"{args.out} exists (golden files are never regenerated; --force to overwrite)")
        return 1
    save_tree(golden_tree(), args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
