"""How much of the gap to the oracle is reaction time? Two measurements on the same throws.

1. ``seen k``: the oracle (true crossing point, minimum-time move) started when the k-th
   detection of the flight is delivered, k = 1..5: what perfect knowledge from that detection
   on could block. No planner knows the velocity from one detection.
2. ``same start``: for each planner, the oracle started at the moment the planner itself first
   moved: how much the planner loses to perfect knowledge given its own start.

    python bench/reaction.py --throws 200 [--tree trees/irb1600_default.h5] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
from pathlib import Path

import numpy as np

from thinkfast.compile.treefile import load_tree
from thinkfast.machine import machine_info
from thinkfast.robot.model import load_robot
from thinkfast.runtime.config import RunConfig
from thinkfast.sim import lockstep as ls
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.throws import ThrowConfig, sample_throws

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"
_W: dict = {}


def _init(tree: str) -> None:
    _W["world"] = ls.World(
        load_tree(tree), load_robot(), RunConfig(), ServoConfig(), CameraModelConfig()
    )


def _one(job) -> dict:
    i, th, seed = job
    w = _W["world"]
    t_rel = ls.LEAD + th.t_release
    cam_seed = seed * 100_003 + i  # the bench's camera noise for throw i
    dets = observe(th, w.camera, w.cfg.camera, np.random.default_rng(cam_seed), t_rel)
    seen = sorted(d.delivery_time for d in dets if d.capture_stamp > t_rel)

    def oracle_from(delay: float) -> bool:
        return ls.simulate(w, th, "oracle", cam_seed, oracle_start=delay).blocked

    out = {"seen": [k < len(seen) and oracle_from(seen[k] - t_rel) for k in range(5)]}
    for p in ("tree", "naive"):
        o = ls.simulate(w, th, p, cam_seed)
        out[p] = (o.blocked, math.isfinite(o.start) and oracle_from(o.start))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", default=str(DEFAULT_TREE))
    ap.add_argument("--throws", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    throws = sample_throws(ThrowConfig(), args.throws, args.seed)
    jobs = [(i, th, args.seed) for i, th in enumerate(throws)]
    with mp.get_context("fork").Pool(args.jobs, _init, (args.tree,)) as pool:
        rows = pool.map(_one, jobs)
    n = len(rows)
    seen = [sum(r["seen"][k] for r in rows) / n for k in range(5)]
    same = {
        p: {
            "planner": sum(r[p][0] for r in rows) / n,
            "oracle_same_start": sum(r[p][1] for r in rows) / n,
        }
        for p in ("tree", "naive")
    }
    out = {"throws": n, "seed": args.seed, "seen_k": seen, "same_start": same}
    out["machine"] = machine_info()
    if args.json:
        print(json.dumps(out))
        return
    print(f"{n} throws (seed {args.seed})")
    print("oracle from the k-th flight detection:")
    for k, r in enumerate(seen, 1):
        print(f"  k={k}: {100 * r:5.1f} %")
    print("planner vs the oracle started when the planner first moved:")
    for p, e in same.items():
        print(
            f"  {p:<6} {100 * e['planner']:5.1f} %   oracle {100 * e['oracle_same_start']:5.1f} %"
        )


if __name__ == "__main__":
    main()
