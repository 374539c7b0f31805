"""Lockstep vs real time: the same throws, the same camera noise, throw by throw.

    .venv/bin/python bench/lockstep_vs_realtime.py --tree trees/irb1600_default.h5 \\
        --throws 50 --seed 1 --planner tree [--json]

Lockstep (``thinkfast-sim bench``) steps the executor, supervisor and controller model in
simulated time; real time (``thinkfast-sim run``) runs the real ``thinkfast-run`` process, the
simulated controller over UDP EGM at 250 Hz and the camera's detections over zenoh on the wall
clock. Both draw the same throws (default mix) with the same per-throw camera noise
(``seed * 100003 + i``). The table gives each mode's blocked count and the throws whose outcome
differs; the acceptance is the same outcome on at least 90 % of the throws. Run it on an idle
machine: in real time a decision that comes a tick late changes a close throw.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thinkfast.machine import machine_info  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, required=True, help="compiled tree (.h5)")
    parser.add_argument("--throws", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--planner", default="tree", help="tree, tree-rest, naive, naive-paper")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)

    from thinkfast.control.config import RunConfig
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.bench import run_bench
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World
    from thinkfast.sim.realtime import run_with_daemon
    from thinkfast.sim.throws import ThrowConfig, sample_throws
    from thinkfast.tree.file import load_tree

    cfg, robot = RunConfig(), load_robot()
    balls = sample_throws(ThrowConfig(), args.throws, args.seed)
    load0 = os.getloadavg()
    rt = run_with_daemon(
        args.tree, args.planner, robot, balls, args.seed, cfg.camera, "thinkfast", None, None,
        report=(lambda line: None) if args.json else print,
    )  # fmt: skip
    load1 = os.getloadavg()

    def world():
        return World(load_tree(args.tree), robot, cfg, ServoConfig(), CameraModelConfig())

    ls = run_bench(world, balls, [args.planner], args.seed, jobs=2)
    rt_by = {r.throw_id: r.blocked for r in rt}
    ls_by = {o.throw_id: o.blocked for o in ls}
    ids = [b.id for b in balls]
    differ = [i for i in ids if rt_by.get(i) != ls_by.get(i)]
    same = len(ids) - len(differ)
    out = {
        "planner": args.planner,
        "throws": len(ids),
        "seed": args.seed,
        "realtime_blocked": int(sum(rt_by.get(i, False) for i in ids)),
        "lockstep_blocked": int(sum(ls_by.get(i, False) for i in ids)),
        "same_outcome": same,
        "same_share": round(same / max(len(ids), 1), 4),
        "differ": [
            {"id": i, "realtime": bool(rt_by.get(i)), "lockstep": bool(ls_by.get(i))}
            for i in differ
        ],
        "load_average_realtime": [round(x, 2) for x in (*load0, *load1)],
        "machine": machine_info(),
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"{args.planner}, {len(ids)} throws, seed {args.seed}: real time "
            f"{out['realtime_blocked']} blocked, lockstep {out['lockstep_blocked']} blocked, "
            f"same outcome on {same} / {len(ids)} ({100 * out['same_share']:.0f} %)"
        )
        for d in out["differ"]:
            print(f"  {d['id']}: real time {d['realtime']}, lockstep {d['lockstep']}")
        print(f"  load average before / after the real-time run: {out['load_average_realtime']}")
    return 0 if out["same_share"] >= 0.9 else 1


if __name__ == "__main__":
    raise SystemExit(main())
