"""Time one full decision update: filter step + delta method + all terminal values + backup + best
child, on a synthetic action tree (or a compiled one with --tree).

    .venv/bin/python bench/decision.py            # table
    .venv/bin/python bench/decision.py --json     # one JSON object
    .venv/bin/python bench/decision.py --tree trees/irb1600_default.h5

With ``--tree``, the daemon's planners are also timed side by side in one run: the executor's
whole handling of a detection that ends in a decision (filter, launch fit, crossing belief and
the planner's choice), on the same simulated detections (default throw mix, camera model, as
``thinkfast-sim`` draws them) for ``tree-rest`` (the paper's at-rest tree values and backup),
``tree`` (the re-rooted choice by the moving shield's block probability), ``tree+branches``
(the same with ``[choice] branches = true``: the compiled child edges scored too) and ``naive``;
``mpc`` and ``jpl`` when named (``--planners tree,mpc,jpl``): their decisions, and each solve's
time with the share over the planner's deadline and the share that failed.
The tree planner's hedge stage (``[hedge]``, before the launch is confirmed: early belief,
target and checked move) is timed on the same detections as ``<planner> hedge stage``, the
calls that ran it; ``hedge_over_commit_p99`` is its p99 over the committed decisions' p99.

The beliefs come from simulated throws (6-8 m, 0.4-0.8 s flight, 50 Hz, a few cm of noise, with
drag), so the belief width sweeps from wide (first frames) to tight (just before the crossing).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thinkfast.decide import backup as bk  # noqa: E402
from thinkfast.decide import values as vl  # noqa: E402
from thinkfast.estimate import crossing as dm  # noqa: E402
from thinkfast.estimate import filter as kf  # noqa: E402
from thinkfast.link import gc_rule  # noqa: E402
from thinkfast.machine import machine_info  # noqa: E402

PLANE = 0.8  # m, intercept plane x = PLANE in base
RADIUS = 0.15  # m, shield radius (assumption for the bench)


def synthetic_tree(branching: int = 13, depth: int = 3, spacing: float = 0.15, seed: int = 0):
    """A tree in the ARCHITECTURE.md layout with a realistic shape.

    Goals on a ``spacing`` grid over y in [-0.9, 0.9], z in [0.3, 1.8]. Every node has a point on
    the plane that drifts from the home point as the tree deepens; each leaf connects to the 3-6
    goals nearest its point and each inner node below the root to 1-2; arrival times are the
    node's time-to-come plus a 0.1-0.4 s move, so 0.2-0.9 s.
    """
    rng = np.random.default_rng(seed)
    gy, gz = np.meshgrid(np.arange(-0.9, 0.9 + 1e-9, spacing), np.arange(0.3, 1.8 + 1e-9, spacing))
    goal_yz = np.column_stack([gy.ravel(), gz.ravel()])
    sizes = [branching**d for d in range(depth + 1)]
    n = sum(sizes)
    node_depth = np.repeat(np.arange(depth + 1), sizes).astype(np.int32)
    level_start = np.concatenate([[0], np.cumsum(sizes)])
    node_parent = np.full(n, -1, dtype=np.int32)
    child_start = np.zeros(n, dtype=np.int64)
    child_count = np.zeros(n, dtype=np.int64)
    point = np.zeros((n, 2))
    point[0] = (0.0, 1.05)
    ttc = np.zeros(n)
    for d in range(depth):
        lo, hi = level_start[d], level_start[d + 1]
        kids = np.arange(level_start[d + 1], level_start[d + 2])
        parent = np.repeat(np.arange(lo, hi), branching)
        node_parent[kids] = parent
        child_start[lo:hi] = level_start[d + 1] + branching * np.arange(hi - lo)
        child_count[lo:hi] = branching
        point[kids] = point[parent] + rng.normal(0.0, 0.45 / (d + 1), (len(kids), 2))
        ttc[kids] = ttc[parent] + rng.uniform(0.05, 0.15, len(kids))
    point[:, 0] = np.clip(point[:, 0], -0.9, 0.9)
    point[:, 1] = np.clip(point[:, 1], 0.3, 1.8)
    n_term = np.where(node_depth == depth, rng.integers(3, 7, n), rng.integers(1, 3, n))
    n_term[0] = 0
    nearest = np.empty((n, 6), dtype=np.intp)
    for lo in range(0, n, 8192):  # chunks keep the distance matrix small for huge trees
        dist = np.linalg.norm(point[lo : lo + 8192, None, :] - goal_yz[None, :, :], axis=2)
        part = np.argpartition(dist, 6, axis=1)[:, :6]
        order = np.argsort(np.take_along_axis(dist, part, axis=1), axis=1)
        nearest[lo : lo + 8192] = np.take_along_axis(part, order, axis=1)
    term_node = np.repeat(np.arange(n), n_term).astype(np.int32)
    rank = np.arange(len(term_node)) - np.repeat(np.cumsum(n_term) - n_term, n_term)
    term_goal = nearest[term_node, rank].astype(np.int32)
    term_arrival = ttc[term_node] + rng.uniform(0.1, 0.4, len(term_node))
    term_start = (np.cumsum(n_term) - n_term).astype(np.int64)
    return SimpleNamespace(
        node_parent=node_parent,
        node_depth=node_depth,
        node_ttc=ttc,
        node_state=np.zeros((n, 9)),
        child_start=child_start,
        child_count=child_count,
        term_start=term_start,
        term_count=n_term.astype(np.int64),
        term_node=term_node,
        term_goal=term_goal,
        term_arrival=term_arrival,
        goal_yz=goal_yz,
        goal_q=np.zeros((len(goal_yz), 6)),
    )


def tree_for_terminals(target: int, seed: int = 0):
    """A depth-3 synthetic tree with about ``target`` terminal edges (branching from the size)."""
    branching = max(2, round((target / 4.5) ** (1.0 / 3.0)))
    return synthetic_tree(branching=branching, seed=seed)


def throws(n: int, seed: int = 1, noise: float = 0.03, rate: float = 50.0):
    """Measurement sequences ``[(t, z), ...]`` of ``n`` simulated throws with drag."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        x0, flight = rng.uniform(6.0, 8.0), rng.uniform(0.4, 0.8)
        target = np.array([PLANE, rng.uniform(-0.7, 0.7), rng.uniform(0.5, 1.6)])
        p = np.array([x0 + PLANE, rng.uniform(-0.5, 0.5), rng.uniform(1.0, 2.0)])
        v = (target - p) / flight
        v[2] += 0.5 * 9.81 * flight
        dt, k, t, seq = 1.0 / rate, 0.01, 0.0, []
        while p[0] > PLANE:
            if rng.random() > 0.05:  # 5 % dropped frames
                seq.append((t, p + rng.normal(0.0, noise, 3)))
            for _ in range(10):  # integrate drag finely
                a = np.array([0.0, 0.0, -9.81]) - k * np.linalg.norm(v) * v
                p, v = p + v * dt / 10, v + a * dt / 10
            t += dt
        out.append(seq)
    return out


class Decision:
    """The per-update pipeline, as the daemon composes it."""

    def __init__(self, tree, fcfg=None, vcfg=None):
        self.tree = tree
        self.fcfg = fcfg or kf.FilterConfig()
        self.vlay = vl.layout(tree.goal_yz, tree.term_goal, RADIUS, vcfg or vl.ValueConfig())
        self.blay = bk.backup_layout(
            tree.node_depth, tree.child_start, tree.child_count, tree.term_start, tree.term_count
        )
        self.arrival = np.asarray(tree.term_arrival, dtype=float)

    def update(self, belief, t, z, elapsed, node=0):
        """One update; returns (belief, best child of ``node``, its value)."""
        belief, _ = kf.update(belief, t, z, self.fcfg)
        if belief.n_meas < 2:
            return belief, -1, 0.0
        cross = dm.crossing(belief.mean, belief.cov, PLANE, self.fcfg.gravity)
        if not cross.ok:
            return belief, -1, 0.0
        tv = vl.terminal_values(self.vlay, cross.mean, cross.cov, self.arrival - elapsed)
        back = bk.backup(self.blay, tv.value, tv.goal_mass)
        return belief, bk.best_child(self.blay, back.value, node), float(back.value[node])


def time_updates(tree, n_throws: int = 40, repeat: int = 3) -> np.ndarray:
    """Durations [s] of every update past initialisation over simulated throws."""
    dec = Decision(tree)
    seqs = throws(n_throws)
    times = []
    for _ in range(repeat):
        for seq in seqs:
            belief = kf.empty(dec.fcfg)
            t_start = seq[0][0] + 0.1  # the robot starts moving 100 ms into the throw
            for t, z in seq:
                elapsed = max(0.0, t - t_start)
                t0 = time.perf_counter()
                belief, _, _ = dec.update(belief, t, z, elapsed)
                dt = time.perf_counter() - t0
                if belief.n_meas > 2:
                    times.append(dt)
    return np.array(times)


def time_planners(tree_path: Path, planners, n_throws: int = 60, seed: int = 1) -> dict:
    """Per planner, durations [ms] of ``Executor.on_detection`` calls that made a decision, on the
    same detections of ``n_throws`` simulated throws (planners interleaved per throw, so a
    change of machine load hits them alike). Garbage is collected as the daemon does it:
    never inside a decision, after it when the interpreter's thresholds say so (untimed)."""
    from thinkfast.control.config import RunConfig
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.cli_options import throw_config, tree_cell
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World
    from thinkfast.sim.throws import sample_throws

    cfg = RunConfig()
    tree, robot, plane = tree_cell(tree_path, cfg)  # the tree's robot and cell
    world = World(tree, robot, cfg, ServoConfig(), CameraModelConfig())
    balls = sample_throws(throw_config(None, plane), n_throws, seed=seed)
    names = [*planners, *(f"{p} hedge stage" for p in planners)]
    out: dict[str, list[float]] = {p: [] for p in names}
    warm: dict[str, list[float]] = {p: [] for p in names}
    passes = [(0, balls[0], warm)] + [(i, b, out) for i, b in enumerate(balls)]
    gc_rule.hold()  # as the daemon: no collection inside a decision, one after it, untimed
    try:
        _fly(passes, world, cfg, planners, seed)
    finally:
        gc_rule.release()
    return {p: np.array(v) for p, v in out.items() if v or p in planners}


SOLVES: dict[str, dict] = {}  # per optimisation planner: its solves' times and failures


def _keep_solves(planner: str, ex, cfg, keep: dict) -> None:
    """An optimisation planner's solves of one throw into :data:`SOLVES` (timed passes only)."""
    stats = getattr(ex.planner, "stats", None)
    if stats is None or keep is None:
        return
    deadline = getattr(ex.planner.settings, "deadline", float("inf"))
    acc = SOLVES.setdefault(planner, {"times": [], "failed": {}, "deadline": deadline})
    acc["times"].extend(stats.times)
    for reason, n in stats.failed.items():
        acc["failed"][reason] = acc["failed"].get(reason, 0) + n


def solve_rows() -> list[dict]:
    """Per optimisation planner: solves, their time [ms] (median, p99, max), the share that
    failed (by reason) and the share that took longer than the planner's deadline."""
    rows = []
    for planner, acc in SOLVES.items():
        ms = np.asarray(acc["times"]) * 1e3
        n = len(ms)
        failed = sum(acc["failed"].values())
        rows.append({
            "planner": planner, "solves": n,
            "solve_p50_ms": round(float(np.percentile(ms, 50)), 3) if n else None,
            "solve_p99_ms": round(float(np.percentile(ms, 99)), 3) if n else None,
            "solve_max_ms": round(float(ms.max()), 3) if n else None,
            "deadline_ms": round(1e3 * acc["deadline"], 1),
            "over_deadline": round(float(np.mean(ms > 1e3 * acc["deadline"])), 4) if n else None,
            "failed": round(failed / n, 4) if n else None,
            "failed_by_reason": {k: v for k, v in acc["failed"].items() if v},
        })  # fmt: skip
    return rows


def _fly(passes, world, cfg, planners, seed: int) -> None:
    """Every pass's throw through each planner's executor, the decisions timed into ``keep``."""
    from thinkfast.control.executor import Executor
    from thinkfast.control.intake import Intake
    from thinkfast.sim.camera import detection_payload, observe
    from thinkfast.sim.lockstep import DT, LEAD

    for i, ball, keep in passes:  # the first throw once more first, to warm up (not kept)
        t_rel = LEAD + ball.t_release
        dets = observe(ball, world.camera, cfg.camera, np.random.default_rng(seed + i), t_rel)
        for planner in planners:
            ex = Executor(world.tree, world.robot, *_planner_config(cfg, planner))
            ex.start_from(world.robot.home, 0.0)
            hedged = _watch_hedge(ex)
            intake = Intake(cfg.camera, cfg.detections)
            t_end = t_rel + ball.flight_time + 0.3
            k, t = 0, 0.0
            while t <= t_end:  # the lockstep loop: detections as delivered, a setpoint per tick
                while k < len(dets) and dets[k].delivery_time <= t:
                    acc = intake.take(detection_payload(dets[k]), None)
                    k += 1
                    if acc is None:
                        continue
                    before = ex.episode.decisions + ex.episodes
                    hedged[0] = False
                    t0 = time.perf_counter()
                    ex.on_detection(t, acc.stamp, acc.position)
                    dt = time.perf_counter() - t0
                    if ex.episode.decisions + ex.episodes > before:
                        keep[planner].append(dt * 1e3)
                    elif hedged[0]:
                        keep[f"{planner} hedge stage"].append(dt * 1e3)
                    gc_rule.collect_due()
                ex.setpoint(t)
                t += DT
            _keep_solves(planner, ex, cfg, keep if keep is not passes[0][2] else None)


def _watch_hedge(ex) -> list[bool]:
    """A flag set whenever ``ex`` runs its hedge stage (for the timing above)."""
    flag = [False]
    if ex.hedge is None:
        return flag
    run = ex.hedge.on_belief

    def hedge(*args):
        flag[0] = True
        return run(*args)

    ex.hedge.on_belief = hedge
    return flag


def _planner_config(cfg, name: str):
    """(config, executor planner) for a timed name: ``tree+branches`` is ``tree`` with the
    compiled branches among its options."""
    import dataclasses

    if name == "tree+branches":
        choice = dataclasses.replace(cfg.choice, branches=True)
        return dataclasses.replace(cfg, choice=choice), "tree"
    return cfg, name  # a registered planner (the hedge variants set their own [hedge] mode)


def planner_rows(times: dict) -> list[dict]:
    rows = []
    for p, ms in times.items():
        rows.append(
            {
                "planner": p,
                "decisions": int(len(ms)),
                "p50_ms": round(float(np.percentile(ms, 50)), 4) if len(ms) else None,
                "p99_ms": round(float(np.percentile(ms, 99)), 4) if len(ms) else None,
                "max_ms": round(float(ms.max()), 4) if len(ms) else None,
            }
        )
    return rows


def memory_bytes(tree) -> int:
    """Bytes of the tree's arrays plus the value and backup layouts an update reads."""
    dec = Decision(tree)
    arrays = [a for a in vars(tree).values() if isinstance(a, np.ndarray)]
    arrays += [a for a in dec.vlay if isinstance(a, np.ndarray)]
    arrays += [a for a in dec.blay if isinstance(a, np.ndarray)]
    arrays += [a for lev in dec.blay.levels for a in lev if isinstance(a, np.ndarray)]
    return int(sum(a.nbytes for a in arrays))


def machine() -> dict:
    """The machine the figures come from (shared with the other benchmarks)."""
    return machine_info()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--tree", type=Path, help="compiled tree file (.h5) instead of synthetic")
    parser.add_argument("--throws", type=int, default=40, help="simulated throws per run")
    parser.add_argument("--no-scaling", action="store_true", help="skip the 10^3..10^6 table")
    parser.add_argument(
        "--planners",
        default="tree-rest,tree,tree+branches,naive",
        help="with --tree: daemon planners timed side by side (comma separated; '' skips)",
    )
    parser.add_argument("--planner-throws", type=int, default=60, help="throws for --planners")
    args = parser.parse_args(argv)

    if args.tree is not None:
        from thinkfast.tree.file import load_tree  # lazy: h5py only when asked

        tree, source = load_tree(args.tree), str(args.tree)
    else:
        tree, source = synthetic_tree(), "synthetic (branching 13, depth 3, goals every 0.15 m)"
    gc.collect()
    times = time_updates(tree, args.throws) * 1e3
    result = {
        "tree": source,
        "terminals": int(len(tree.term_goal)),
        "nodes": int(len(tree.node_depth)),
        "goals": int(len(tree.goal_yz)),
        "updates": int(len(times)),
        "p50_ms": round(float(np.percentile(times, 50)), 4),
        "p99_ms": round(float(np.percentile(times, 99)), 4),
        "max_ms": round(float(times.max()), 4),
        "machine": machine(),
    }
    if args.tree is not None and args.planners:
        names = [p.strip() for p in args.planners.split(",") if p.strip()]
        rows = planner_rows(time_planners(args.tree, names, args.planner_throws))
        result["planners"] = rows
        if SOLVES:
            result["solves"] = solve_rows()
        by = {r["planner"]: r for r in rows}
        if by.get("tree-rest", {}).get("p99_ms") and by.get("tree", {}).get("p99_ms"):
            result["tree_over_tree_rest_p99"] = round(
                by["tree"]["p99_ms"] / by["tree-rest"]["p99_ms"], 3
            )
        for p in names:
            stage = by.get(f"{p} hedge stage", {}).get("p99_ms")
            if stage and by.get(p, {}).get("p99_ms"):
                result["hedge_over_commit_p99"] = round(stage / by[p]["p99_ms"], 3)
        if by.get("tree-rest", {}).get("p99_ms") and by.get("tree+branches", {}).get("p99_ms"):
            result["branches_over_tree_rest_p99"] = round(
                by["tree+branches"]["p99_ms"] / by["tree-rest"]["p99_ms"], 3
            )
    result["load_average"] = [round(x, 2) for x in os.getloadavg()]
    if not args.no_scaling:
        rows = []
        for target in (10**3, 10**4, 10**5, 10**6):
            t = tree_for_terminals(target)
            ms = (
                time_updates(
                    t, n_throws=max(3, args.throws // (4 if target < 10**5 else 20)), repeat=1
                )
                * 1e3
            )
            rows.append(
                {
                    "terminals": int(len(t.term_goal)),
                    "nodes": int(len(t.node_depth)),
                    "p50_ms": round(float(np.percentile(ms, 50)), 4),
                    "p99_ms": round(float(np.percentile(ms, 99)), 4),
                    "memory_mb": round(memory_bytes(t) / 2**20, 2),
                }
            )
        result["scaling"] = rows
    if args.json:
        print(json.dumps(result))
        return 0
    m = result["machine"]
    print(f"decision update: {result['tree']}")
    print(
        f"  {result['nodes']} nodes, {result['terminals']} terminals, {result['goals']} goals, "
        f"{result['updates']} updates"
    )
    print(f"  {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}")
    print(f"  {'terminals':>10} {'nodes':>9} {'p50 ms':>9} {'p99 ms':>9} {'MB':>8}")
    print(
        f"  {result['terminals']:>10} {result['nodes']:>9} {result['p50_ms']:>9.3f} "
        f"{result['p99_ms']:>9.3f}   (default)"
    )
    for row in result.get("scaling", []):
        print(
            f"  {row['terminals']:>10} {row['nodes']:>9} {row['p50_ms']:>9.3f} "
            f"{row['p99_ms']:>9.3f} {row['memory_mb']:>8.2f}"
        )
    if "planners" in result:
        print("executor decisions (on_detection that decided), same detections:")
        print(f"  {'planner':>18} {'decisions':>9} {'p50 ms':>9} {'p99 ms':>9} {'max ms':>9}")
        for r in result["planners"]:
            print(
                f"  {r['planner']:>18} {r['decisions']:>9} {r['p50_ms']:>9.3f} "
                f"{r['p99_ms']:>9.3f} {r['max_ms']:>9.3f}"
            )
        if "tree_over_tree_rest_p99" in result:
            print(f"  p99 tree / tree-rest: {result['tree_over_tree_rest_p99']:.2f}")
        if "hedge_over_commit_p99" in result:
            print(f"  p99 hedge stage / committed: {result['hedge_over_commit_p99']:.2f}")
        if "branches_over_tree_rest_p99" in result:
            ratio = result["branches_over_tree_rest_p99"]
            print(f"  p99 tree+branches / tree-rest: {ratio:.2f}")
    for r in result.get("solves", []):
        print(
            f"  {r['planner']} solves: {r['solves']}, {r['solve_p50_ms']} / {r['solve_p99_ms']} / "
            f"{r['solve_max_ms']} ms (median / p99 / max); over its {r['deadline_ms']} ms "
            f"deadline {100 * r['over_deadline']:.1f} %; failed {100 * r['failed']:.1f} % "
            f"{r['failed_by_reason']}"
        )
    print(f"  load average at the end: {result['load_average']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
