"""Lockstep throws with an exact controller clock and with one that is not hard real-time.

The same throws (the simulator's mix, feints included) and camera noise, once with the exact
clock and once with :class:`~thinkfast.sim.controller.ClockJitter` (``tm`` +-1 ms in whole ms,
1 % repeats, 10-50 ms jumps while the servo moves one cycle per packet; the core counts the
cycles by ``seqno``). Prints, per clock, the throws blocked and the supervisor's interventions
per tick (ticks counted from the first frame to the crossing: fewer than were stepped), and the
paired difference in blocks over the throws that are not feints (95 % interval, exact McNemar
p); ``--json``: one JSON object.

    python bench/clock_jitter.py --throws 200 --planner tree --json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from thinkfast.control.config import RunConfig
from thinkfast.robot.model import default_robot_path, load_robot
from thinkfast.sim.camera import CameraModelConfig
from thinkfast.sim.controller import ClockJitter, ServoConfig
from thinkfast.sim.lockstep import DT, LEAD, World, simulate
from thinkfast.sim.stats import compare
from thinkfast.sim.throws import ThrowConfig, sample_throws
from thinkfast.tree.file import load_tree

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", default=str(DEFAULT_TREE), help="tree file (default: the default)")
    ap.add_argument("--throws", type=int, default=200, help="throws (200), plus a tenth feints")
    ap.add_argument("--seed", type=int, default=1, help="throws and camera noise (1)")
    ap.add_argument("--planner", default="tree", choices=("tree", "naive"))
    ap.add_argument("--stall-rate", type=float, default=0.5, help="clock jumps per second (0.5)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args(argv)
    robot, cfg = load_robot(default_robot_path()), RunConfig()
    tree = load_tree(a.tree)
    clocks = {"exact": None, "jitter": ClockJitter(stall_rate=a.stall_rate, seed=a.seed)}
    worlds = {
        k: World(tree, robot, cfg, ServoConfig(), CameraModelConfig(), clock=c)
        for k, c in clocks.items()
    }
    throws = sample_throws(ThrowConfig(), a.throws, a.seed, feints=a.throws // 10)
    started = time.time()
    res = {k: {"blocked": [], "intervened": 0, "ticks": 0, "faults": 0} for k in clocks}
    for i, th in enumerate(throws):
        for k, world in worlds.items():
            out = simulate(world, th, a.planner, seed=a.seed * 100_003 + i)
            r = res[k]
            r["blocked"].append(bool(out.blocked))
            r["intervened"] += out.intervened
            r["faults"] += out.faults
            r["ticks"] += int((LEAD + th.t_release + th.flight_time) / DT)
    real = [th.kind != "feint" for th in throws]  # feints are never blocked
    ex = [b for b, r in zip(res["exact"]["blocked"], real, strict=True) if r]
    paired = compare(ex, [b for b, r in zip(res["jitter"]["blocked"], real, strict=True) if r])
    summary = {
        k: {
            "blocked": sum(r["blocked"]),
            "intervened": r["intervened"],
            "ticks_at_least": r["ticks"],
            "intervened_pct": round(100.0 * r["intervened"] / max(1, r["ticks"]), 4),
            "faults": r["faults"],
        }
        for k, r in res.items()
    }
    out = {
        "planner": a.planner, "throws": len(throws), "seed": a.seed, "clocks": summary,
        "paired_jitter_vs_exact": paired,
        "stall_rate": a.stall_rate, "seconds": round(time.time() - started, 1),
        "load_avg": [round(x, 2) for x in os.getloadavg()],
    }  # fmt: skip
    if a.json:
        print(json.dumps(out))
        return 0
    print(f"{len(throws)} throws ({a.planner}), seed {a.seed}, clock jumps {a.stall_rate:g}/s")
    for k, s in summary.items():
        print(f"  {k:<7} blocked {s['blocked']:4d}  intervened {s['intervened']:5d} of >= "
              f"{s['ticks_at_least']} ticks ({s['intervened_pct']:.3f} %)  "
              f"faults {s['faults']}")  # fmt: skip
    p = paired
    print(f"  paired (jitter - exact, {p['throws']} throws): {100 * p['difference']:+.1f} points, "
          f"95 % [{100 * p['ci95'][0]:+.1f}, {100 * p['ci95'][1]:+.1f}], only exact "
          f"{p['only_reference']}, only jitter {p['only_other']}, "
          f"McNemar p {p['p_exact']:.3g}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
