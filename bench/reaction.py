"""How much of the gap to the oracle is reaction time? Two measurements on the same throws.

1. ``seen k``: the oracle (true crossing point, minimum-time move) started when the k-th
   detection of the flight is delivered, k = 1..5: what perfect knowledge from that detection
   on could block. No planner knows the velocity from one detection.
2. ``same start``: for each planner, the oracle started at the moment the planner itself first
   moved: how much the planner loses to perfect knowledge given its own start.

Both overall and by kind of throw (the default mix: still holds and wind-ups).

    python bench/reaction.py --throws 200 [--tree trees/irb1600_default.h5] [--json]
        [--cameras base,side] [--planners tree,tree-hedge-none,naive]

``--planners``: the planners of measurement 2 (default: the tree, which hedges, the launch-gated
tree ``tree-hedge-none`` and naive).

``--cameras`` (as ``thinkfast-sim bench --cameras``, docs/CAMERAS.md): the cameras that see the
throws; "seen k" counts flight detections of any camera.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
from pathlib import Path

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.machine import machine_info
from thinkfast.sim import lockstep as ls
from thinkfast.sim.camera import CameraModelConfig, observe_cameras
from thinkfast.sim.cli import with_cameras
from thinkfast.sim.cli_options import tree_cell
from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.throws import ThrowConfig, sample_throws

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"
PLANNERS = ("tree", "tree-hedge-none", "naive")  # the default tree hedges; the gated one beside
_W: dict = {}


def _init(tree: str, cameras: str | None = None, planners: tuple = PLANNERS) -> None:
    _W["planners"] = planners
    cfg = with_cameras(RunConfig(), cameras)
    t, robot, _ = tree_cell(Path(tree), cfg)  # the tree's robot, placed in its plane
    _W["world"] = ls.World(t, robot, cfg, ServoConfig(), CameraModelConfig())


def _one(job) -> dict:
    i, th, seed = job
    w = _W["world"]
    t_rel = ls.LEAD + th.t_release
    cam_seed = seed * 100_003 + i  # the bench's camera noise for throw i
    dets = observe_cameras(th, w.cameras, cam_seed, t_rel)
    seen = sorted(d.delivery_time for d in dets if d.capture_stamp > t_rel)

    def oracle_from(delay: float) -> bool:
        return ls.simulate(w, th, "oracle", cam_seed, oracle_start=delay).blocked

    out = {
        "kind": th.kind,
        "seen": [k < len(seen) and oracle_from(seen[k] - t_rel) for k in range(5)],
    }
    out["first_seen"] = seen[0] - t_rel if seen else math.nan
    for p in _W["planners"]:
        o = ls.simulate(w, th, p, cam_seed)
        out[p] = (o.blocked, math.isfinite(o.start) and oracle_from(o.start), o.start)
    return out


def _summary(rows: list[dict], planners: tuple) -> dict:
    n = len(rows)
    out = {
        "throws": n,
        "seen_k": [sum(r["seen"][k] for r in rows) / n for k in range(5)],
        "first_seen_median_s": float(np.nanmedian([r["first_seen"] for r in rows])),
    }
    for p in planners:
        starts = [r[p][2] for r in rows if math.isfinite(r[p][2])]
        out[p] = {
            "planner": sum(r[p][0] for r in rows) / n,
            "oracle_same_start": sum(r[p][1] for r in rows) / n,
            "start_median_s": float(np.median(starts)) if starts else math.nan,
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", default=str(DEFAULT_TREE))
    ap.add_argument("--throws", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--cameras", default=None, help="e.g. base,side (default: the base camera)")
    ap.add_argument("--planners", default=",".join(PLANNERS), help="comma separated")
    args = ap.parse_args()
    throws = sample_throws(ThrowConfig(), args.throws, args.seed)
    jobs = [(i, th, args.seed) for i, th in enumerate(throws)]
    planners = tuple(p for p in args.planners.split(",") if p)
    with mp.get_context("fork").Pool(args.jobs, _init, (args.tree, args.cameras, planners)) as pool:
        rows = pool.map(_one, jobs)
    kinds = sorted({r["kind"] for r in rows})
    out = {"seed": args.seed, "cameras": args.cameras or "base", "all": _summary(rows, planners)}
    out["by_kind"] = {k: _summary([r for r in rows if r["kind"] == k], planners) for k in kinds}
    out["machine"] = machine_info()
    if args.json:
        print(json.dumps(out))
        return
    groups = [("all", out["all"])] + list(out["by_kind"].items())
    print(f"{len(rows)} throws (seed {args.seed}), oracle from the k-th flight detection:")
    print(f"  {'':<8}{'throws':>7}" + "".join(f"{'k=' + str(k):>8}" for k in range(1, 6)))
    for name, g in groups:
        print(f"  {name:<8}{g['throws']:>7}" + "".join(f"{100 * r:7.1f}%" for r in g["seen_k"]))
    print(
        "planner vs the oracle started when the planner first moved (median start after release):"
    )
    for name, g in groups:
        for p in planners:
            e = g[p]
            print(
                f"  {name:<8}{p:<16} {100 * e['planner']:5.1f} %   oracle same start "
                f"{100 * e['oracle_same_start']:5.1f} %   start {1e3 * e['start_median_s']:4.0f} ms"
                f"   (first detection {1e3 * g['first_seen_median_s']:3.0f} ms)"
            )


if __name__ == "__main__":
    main()
