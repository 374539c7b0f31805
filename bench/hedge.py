"""Hedge stage, paired: the bench's throws flown in pieces that each stay short, then combined.

``thinkfast-sim bench`` flies every throw in one run; on a shared host 1000 throws with two
planners take longer than one run should. This script flies the bench's throws ``--start`` to
``--stop`` (the same throws and camera noise as the bench: throw ``i`` of the seed uses
:func:`thinkfast.sim.bench.throw_seed`) and writes their outcomes as JSON lines; ``combine``
reads the pieces and prints the bench's summary (table, or with ``--json`` one JSON object),
paired against ``--reference``.

    python bench/hedge.py run --tree trees/irb1600_default.h5 --throws 1000 --seed 1 \\
        --planners tree,tree-hedge-none --start 0 --stop 110 --out rows/s1_000.jsonl
    python bench/hedge.py combine rows/s1_*.jsonl --planners tree,tree-hedge-none \\
        --reference tree-hedge-none [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from thinkfast.control.config import load_run_config
from thinkfast.sim.bench import format_summary, run_chunk, summarize
from thinkfast.sim.cli import _throws, _WorldFactory
from thinkfast.sim.lockstep import Outcome


def _run(a) -> None:
    cfg = load_run_config(a.config)
    balls = _throws(a.throws, a.seed, None, a.mix, a.throws // 10 if a.feints < 0 else a.feints)
    stop = len(balls) if a.stop is None else min(a.stop, len(balls))
    world = _WorldFactory(Path(a.tree), cfg)()
    rows = run_chunk(world, balls[a.start : stop], a.planners.split(","), a.seed, a.start)
    with open(a.out, "w", encoding="utf-8") as f:
        for o in rows:
            f.write(json.dumps(o._asdict()) + "\n")
    print(f"{len(rows)} outcomes of throws {a.start}..{stop - 1} -> {a.out}")


def _load(paths: list[str]) -> list[Outcome]:
    rows = []
    for p in sorted(paths):
        with open(p, encoding="utf-8") as f:
            rows += [Outcome(**json.loads(line)) for line in f if line.strip()]
    return rows


def _combine(a) -> None:
    rows = _load(a.rows)
    names = a.planners.split(",")
    summary = summarize(rows, names, a.reference)
    summary["pieces"] = len(a.rows)
    if a.json:
        print(json.dumps(summary, default=lambda x: None if math.isnan(x) else x))
    else:
        print(format_summary(summary))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="fly throws start..stop-1 of the bench's set")
    r.add_argument("--tree", required=True)
    r.add_argument("--throws", type=int, default=1000)
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--mix", default=None)
    r.add_argument("--feints", type=int, default=-1, help="default: a tenth of --throws")
    r.add_argument("--planners", default="tree,tree-hedge-none")
    r.add_argument("--config", default=None)
    r.add_argument("--start", type=int, default=0)
    r.add_argument("--stop", type=int, default=None)
    r.add_argument("--out", required=True)
    c = sub.add_parser("combine", help="summarize the pieces")
    c.add_argument("rows", nargs="+")
    c.add_argument("--planners", default="tree,tree-hedge-none")
    c.add_argument("--reference", default=None)
    c.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    (_run if a.cmd == "run" else _combine)(a)


if __name__ == "__main__":
    sys.exit(main())
