"""Benchmark: check random terminal edges of a compiled tree, as the compiler checks them.

    python bench/pathcheck.py [--tree trees/irb1600_default.h5] [--edges 200] [--json]

Steers each edge from its stored start state to its goal (Ruckig) and checks it with the
default compile parameters (:meth:`PathChecker.check_many`: sampling, wrist, FK, limits,
collisions). Prints CPU milliseconds per edge (best of --repeat), samples and collision checks
per edge; under ``valgrind --tool=callgrind`` with --repeat 1 it gives instruction counts. With
``PYTHONPATH`` at an older checkout it checks one edge at a time, as that code did.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if not os.environ.get("PYTHONPATH"):  # PYTHONPATH may name another checkout to measure
    sys.path.insert(0, str(ROOT))

from thinkfast.compile.pathcheck import PathChecker  # noqa: E402
from thinkfast.machine import machine_info  # noqa: E402
from thinkfast.robot.model import load_robot  # noqa: E402
from thinkfast.robot.steering import Steering  # noqa: E402
from thinkfast.tree.file import load_tree  # noqa: E402


def main(conf: argparse.Namespace) -> None:
    tree = load_tree(conf.tree)
    robot = load_robot()
    steer = Steering.for_robot(robot)
    check = PathChecker(robot, 0.02, 0.01, 0.002)  # trees/irb1600_default.toml [tree]
    pick = np.random.default_rng(conf.seed).choice(tree.n_terminals, conf.edges, replace=False)
    trajs = [steer.steer(tree.node_state[tree.term_node[k]], tree.goal_q[tree.term_goal[k], :3])
             for k in pick]  # fmt: skip
    wrists = tree.node_q[tree.term_node[pick], 3:]
    spans = [t.duration for t in trajs]
    best = np.inf
    for _ in range(conf.repeat):
        start = time.process_time()
        if hasattr(check, "check_many"):
            results = check.check_many(trajs, spans, wrists)
        else:  # an older checkout (PYTHONPATH): one edge at a time
            results = [check.check(t, s, w) for t, s, w in zip(trajs, spans, wrists, strict=True)]
        best = min(best, time.process_time() - start)
    out = {
        "tree": str(conf.tree),
        "edges": conf.edges,
        "cpu_ms_per_edge": round(1e3 * best / conf.edges, 3),
        "checks_per_edge": round(sum(r.checks for r in results) / conf.edges, 1),
        "valid": sum(r.ok for r in results),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "machine": machine_info(),
    }
    if conf.json:
        print(json.dumps(out))
        return
    print(f"{'edges':>6} {'CPU ms/edge':>12} {'checks/edge':>12} {'valid':>6}  load")
    print(f"{out['edges']:>6} {out['cpu_ms_per_edge']:>12.3f} {out['checks_per_edge']:>12.1f} "
          f"{out['valid']:>6}  {out['load_average']}")  # fmt: skip


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=ROOT / "trees" / "irb1600_default.h5")
    parser.add_argument("--edges", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    main(parser.parse_args())
