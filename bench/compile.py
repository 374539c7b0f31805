"""Benchmark: compile the default action tree with 1 and with 2 worker processes.

    python bench/compile.py [--config trees/irb1600_default.toml] [--json]

Prints a table (and with --json one JSON object) with primitives computed, terminals kept, wall
seconds, primitives per second, and the 2-job speed-up. Both runs must give identical datasets.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from thinkfast.compile.build import compile_tree  # noqa: E402
from thinkfast.compile.config import load_compile_config  # noqa: E402
from thinkfast.machine import machine_info  # noqa: E402
from thinkfast.tree.file import tree_fingerprint  # noqa: E402


def primitives(tree) -> int:
    """Primitives computed and checked: kept edges plus the discarded ones."""
    discards = sum(json.loads(tree.meta["tree_discards"]).values())
    discards += sum(json.loads(tree.meta["terminal_discards"]).values())
    return tree.n_nodes - 1 + tree.n_terminals + discards


def run(config: Path, jobs: int) -> tuple[object, float]:
    loaded = load_compile_config(config)
    start = time.perf_counter()
    tree = compile_tree(loaded, jobs=jobs)
    return tree, time.perf_counter() - start


def main(conf: argparse.Namespace) -> None:
    results = {}
    for jobs in (1, 2):
        tree, seconds = run(conf.config, jobs)
        results[jobs] = (tree, seconds)
    (t1, s1), (t2, s2) = results[1], results[2]
    if tree_fingerprint(t1) != tree_fingerprint(t2):
        raise SystemExit("bench/compile.py: --jobs 1 and --jobs 2 gave different trees")
    n = primitives(t2)
    out = {
        "config": str(conf.config),
        "primitives": n,
        "nodes": t2.n_nodes,
        "terminals": t2.n_terminals,
        "fingerprint": tree_fingerprint(t2),
        "seconds": round(s2, 3),
        "seconds_1_job": round(s1, 3),
        "primitives_per_s": round(n / s2, 1),
        "jobs": 2,
        "speedup_2_jobs": round(s1 / s2, 3),
        "machine": machine_info(),
    }
    if conf.json:
        print(json.dumps(out))
        return
    m = out["machine"]
    print(f"compile {conf.config} on {m['cpu']} ({m['cores']} cores), Python {m['python']}")
    print(f"{'jobs':>6} {'seconds':>9} {'primitives':>11} {'prim/s':>9} {'terminals':>10}")
    for jobs, (tree, sec) in results.items():
        print(f"{jobs:>6} {sec:>9.2f} {n:>11} {n / sec:>9.0f} {tree.n_terminals:>10}")
    print(f"speed-up with 2 jobs: {out['speedup_2_jobs']:.2f}x (identical datasets)")
    print(f"fingerprint {out['fingerprint']}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "trees" / "irb1600_default.toml")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    main(parser.parse_args())
