"""Time P(block) of M moving-shield paths per belief update (thinkfast.decide.path_value), and the
cost of sampling the default tree's edges into shield paths (Ruckig + batched FK).

    .venv/bin/python bench/path_value.py                 # table
    .venv/bin/python bench/path_value.py --json          # one JSON object
    .venv/bin/python bench/path_value.py --tree trees/irb1600_default.h5 --dt 0.02

Beliefs: every filter update (past initialisation) of simulated throws (bench/decision.py's
throws: 6-8 m, 0.4-0.8 s, 50 Hz, 3 cm noise, drag), through the delta method. Paths: the tree's
terminal edges (Ruckig from the node's state to rest at the goal, coplanar wrist), sampled every
``--dt``, each starting at its node's time-to-come minus 0.1 s; for every update M of them are
drawn at random (seeded). Times are one core's wall time per call, the first call excluded.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from decision import throws  # noqa: E402

from thinkfast.control.segments import Steering  # noqa: E402
from thinkfast.decide import iso_disk  # noqa: E402
from thinkfast.decide.path_value import block_probability  # noqa: E402
from thinkfast.decide.shield_paths import block_geometry, shield_paths  # noqa: E402
from thinkfast.decide.tree_view import BALL_RADIUS  # noqa: E402
from thinkfast.estimate import crossing as dm  # noqa: E402
from thinkfast.estimate import filter as kf  # noqa: E402
from thinkfast.machine import machine_info  # noqa: E402
from thinkfast.robot.model import load_robot  # noqa: E402
from thinkfast.robot.shield_path import ShieldSampler, sample_joint_paths  # noqa: E402
from thinkfast.tree.file import load_tree  # noqa: E402

PLANE = 0.8


def beliefs(n_throws: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(crossing mean, crossing cov, ball velocity at the plane) of every usable update."""
    fcfg = kf.FilterConfig()
    out = []
    for seq in throws(n_throws):
        belief = kf.empty(fcfg)
        for t, z in seq:
            belief, _ = kf.update(belief, t, z, fcfg)
            if belief.n_meas <= 2:
                continue
            c = dm.crossing(belief.mean, belief.cov, PLANE, fcfg.gravity)
            if c.ok:
                v = belief.mean[3:].copy()
                v[2] -= fcfg.gravity * c.mean[2]
                out.append((c.mean, c.cov, v))
    return out


def edge_paths(tree, robot, dt: float):
    """Shield centres (E, T, 3) of every terminal edge on one grid, with timings [s]."""
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    t0 = time.perf_counter()
    trajs = [steer.to_rest(tree.node_state[n], tree.goal_q[g, :3])
             for n, g in zip(tree.term_node, tree.term_goal, strict=True)]  # fmt: skip
    t1 = time.perf_counter()
    n = int(np.ceil(max(tr.duration for tr in trajs) / dt)) + 1
    times = np.arange(n) * dt
    q = sample_joint_paths(trajs, times)
    t2 = time.perf_counter()
    centre = ShieldSampler(robot).centres(q)
    t3 = time.perf_counter()
    return times, centre, {"ruckig_s": t1 - t0, "sample_s": t2 - t1, "fk_s": t3 - t2}


def storage(tree, dt: float) -> dict:
    """Bytes of float32 shield paths for the tree's edges at spacing ``dt``: ragged (each edge
    its own duration) and padded to the longest edge."""
    out = {}
    for name, dur in (
        ("tree_edges", tree.edge_duration[1:]),
        ("terminal_edges", tree.term_duration),
    ):
        samples = np.ceil(dur / dt).astype(int) + 1
        out[name] = {
            "count": int(len(dur)),
            "ragged_bytes": int(samples.sum() * 12),
            "padded_bytes": int(len(dur) * samples.max() * 12),
        }
    return out


def spacing_error(tree, robot, dt: float, n_edges: int = 300, seed: int = 0) -> float:
    """Largest distance [m] between the shield path sampled every 2 ms and its linear
    interpolation from samples every ``dt``, over random terminal edges."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(tree.n_terminals, min(n_edges, tree.n_terminals), replace=False)
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    trajs = [steer.to_rest(tree.node_state[tree.term_node[k]], tree.goal_q[tree.term_goal[k], :3])
             for k in pick]  # fmt: skip
    fine_t = np.arange(0.0, 1.1, 0.002)
    coarse_t = np.arange(0.0, 1.1 + dt, dt)
    sampler = ShieldSampler(robot)
    fine = sampler.centres(sample_joint_paths(trajs, fine_t))
    coarse = sampler.centres(sample_joint_paths(trajs, coarse_t))
    worst = 0.0
    for m in range(len(trajs)):
        interp = np.stack([np.interp(fine_t, coarse_t, coarse[m, :, j]) for j in range(3)], 1)
        worst = max(worst, float(np.linalg.norm(interp - fine[m], axis=1).max()))
    return worst


def time_calls(paths, start, updates, geom, m: int, seed: int = 0) -> np.ndarray:
    """Wall time [s] of block_probability for M random paths (an index into all the packed
    edges, as the runtime would pass this update's candidates) at every update."""
    rng = np.random.default_rng(seed)
    out = []
    for mean, cov, v in updates:
        pick = rng.choice(paths.n_paths, m, replace=False)
        st = start[pick]
        t0 = time.perf_counter()
        block_probability(paths, mean, cov, geom, v, st, index=pick)
        out.append(time.perf_counter() - t0)
    return np.array(out[1:])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--tree", type=Path, default=Path("trees/irb1600_default.h5"))
    parser.add_argument("--dt", type=float, default=0.02, help="path sample spacing [s]")
    parser.add_argument("--throws", type=int, default=20, help="simulated throws")
    parser.add_argument("--sizes", default="50,200,1000", help="numbers of paths per call")
    args = parser.parse_args(argv)
    if not args.tree.exists():
        parser.error(f"{args.tree}: no such tree (make demo compiles the default one)")

    tree, robot = load_tree(args.tree), load_robot()
    geom = block_geometry(robot, PLANE, BALL_RADIUS)
    t0 = time.perf_counter()
    iso_disk.warm_up()
    table_s = time.perf_counter() - t0
    times, centre, sampling = edge_paths(tree, robot, args.dt)
    t0 = time.perf_counter()
    paths = shield_paths(times, centre, geom)
    sampling["pack_s"] = time.perf_counter() - t0
    start = tree.node_ttc[tree.term_node] - 0.1
    updates = beliefs(args.throws)
    gc.collect()
    rows = []
    for m in (int(s) for s in args.sizes.split(",")):
        ms = time_calls(paths, start, updates, geom, m) * 1e3
        rows.append(
            {
                "paths": m,
                "p50_ms": round(float(np.percentile(ms, 50)), 4),
                "p99_ms": round(float(np.percentile(ms, 99)), 4),
                "max_ms": round(float(ms.max()), 4),
            }
        )
    result = {
        "tree": str(args.tree),
        "dt_s": args.dt,
        "samples_per_path": int(len(times)),
        "updates": len(updates) - 1,
        "calls": rows,
        "table_build_s": round(table_s, 3),
        "sampling": {k: round(v, 3) for k, v in sampling.items()},
        "terminal_edges": int(tree.n_terminals),
        "storage": {f"{dt}": storage(tree, dt) for dt in (0.01, 0.02)},
        "spacing_error_m": {
            f"{dt}": round(spacing_error(tree, robot, dt), 5) for dt in (0.01, 0.02, 0.04)
        },  # fmt: skip
        "machine": machine_info(),
    }
    if args.json:
        print(json.dumps(result))
        return 0
    m = result["machine"]
    print(
        f"path value: {result['tree']}, paths every {args.dt * 1e3:.0f} ms ({len(times)} samples)"
    )
    print(f"  {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}")
    head = f"{'paths':>6} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}"
    print(f"  {result['updates']} belief updates; {head}")
    for r in rows:
        print(f"  {'':>{len(str(result['updates'])) + 16}}{r['paths']:>6} {r['p50_ms']:>8.3f} "
              f"{r['p99_ms']:>8.3f} {r['max_ms']:>8.3f}")  # fmt: skip
    s = result["sampling"]
    print(f"  isotropic disk table: {table_s:.3f} s once per process")
    print(f"  sampling all {tree.n_terminals} terminal edges: Ruckig {s['ruckig_s']:.2f} s, "
          f"samples {s['sample_s']:.2f} s, FK {s['fk_s']:.2f} s, packing {s['pack_s']:.2f} s "
          f"({paths.planes.nbytes / 1e6:.0f} MB in memory)")  # fmt: skip
    for dt, st in result["storage"].items():
        t, e = st["terminal_edges"], st["tree_edges"]
        print(f"  storage at {float(dt) * 1e3:.0f} ms (float32): terminal edges "
              f"{t['ragged_bytes'] / 1e6:.1f} MB ragged / {t['padded_bytes'] / 1e6:.1f} MB padded, "
              f"tree edges {e['ragged_bytes'] / 1e3:.0f} kB")  # fmt: skip
    for dt, err in result["spacing_error_m"].items():
        print(f"  linear interpolation error at {float(dt) * 1e3:.0f} ms: {err * 1e3:.2f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
