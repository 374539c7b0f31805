"""One camera against two: the same throws, the same base-camera noise, paired.

Runs the lockstep bench (``thinkfast-sim bench``'s kernels) once per camera set-up and compares
every planner of every set-up with the reference (default ``tree`` with the base camera alone),
throw by throw (exact McNemar, Newcombe interval). Also the reaction figures: when the first
flight detection is delivered (any camera) and when each planner first moved, medians after
release, overall and per kind of throw.

    python bench/cameras.py --throws 300 [--setups base base,side] [--planners tree,oracle_seen]
        [--tree trees/irb1600_default.h5] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from thinkfast.control.config import load_run_config
from thinkfast.machine import machine_info
from thinkfast.sim.bench import format_summary, run_bench, summarize, throw_seed
from thinkfast.sim.camera import CameraModelConfig, observe_cameras
from thinkfast.sim.cli import _throws, _WorldFactory, with_cameras
from thinkfast.sim.lockstep import LEAD, sim_cameras

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"


def first_seen(cfg, throws, seed: int) -> list[float]:
    """Per throw, when its first flight detection is delivered after release [s] (nan: never)."""
    cams = sim_cameras(cfg, CameraModelConfig())
    out = []
    for i, th in enumerate(throws):
        if th.kind == "feint":
            continue
        t_rel = LEAD + th.t_release
        dets = observe_cameras(th, cams, throw_seed(seed, i), t_rel)
        seen = [d.delivery_time - t_rel for d in dets if d.capture_stamp > t_rel]
        out.append(min(seen) if seen else math.nan)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", default=str(DEFAULT_TREE))
    ap.add_argument("--throws", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--feints", type=int, default=-1, help="default: a tenth of --throws")
    ap.add_argument("--setups", nargs="+", default=["base", "base,side"])
    ap.add_argument("--planners", default="tree,oracle_seen")
    ap.add_argument("--reference", default=None, help="default: the first planner, first set-up")
    ap.add_argument("--config", default=None, help="runtime config (TOML)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    feints = args.throws // 10 if args.feints < 0 else args.feints
    throws = _throws(args.throws, args.seed, None, None, feints)
    base_cfg = load_run_config(args.config)
    outcomes, names, seen = [], [], {}
    start = time.perf_counter()
    for setup in args.setups:
        cfg = with_cameras(base_cfg, setup)
        label = "+".join(setup.split(","))
        world = _WorldFactory(Path(args.tree), cfg)
        rows = run_bench(world, throws, planners, args.seed, args.jobs)
        outcomes += [o._replace(planner=f"{o.planner} {label}") for o in rows]
        names += [f"{p} {label}" for p in planners]
        seen[label] = first_seen(cfg, throws, args.seed)
    summary = summarize(outcomes, names, args.reference or names[0])
    summary["first_seen_median_s"] = {k: float(np.nanmedian(v)) for k, v in seen.items()}
    summary["seconds"] = round(time.perf_counter() - start, 1)
    summary["seed"] = args.seed
    summary["setups"] = args.setups
    summary["machine"] = machine_info()
    if args.json:
        print(json.dumps(summary))
        return
    print(format_summary(summary))
    for k, v in summary["first_seen_median_s"].items():
        print(f"first flight detection delivered ({k}): median {1e3 * v:.0f} ms after release")
    print(f"({summary['seconds']} s)")


if __name__ == "__main__":
    main()
