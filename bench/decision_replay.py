"""The tree planner's decisions, recorded once and replayed with CPU time per call: two
checkouts compared on the same calls, alternately, in one run.

    python bench/decision_replay.py record --tree trees/irb1600_default.h5 --throws 60 \\
        --out /tmp/calls.pkl
    PYTHONPATH=<checkout> python bench/decision_replay.py replay /tmp/calls.pkl --json
    python bench/decision_replay.py compare --old <checkout> --tree trees/irb1600_default.h5

``record`` (this checkout) flies ``--throws`` simulated throws of the default mix against the
default ``tree`` planner exactly as ``bench/decision.py --planners tree`` does (the daemon's
executor fed the detections as delivered, a setpoint per EGM tick) and keeps every decision
call's inputs: each ``Chooser.choose`` (the committed choice: continue, direct moves, scored by
the moving shield's block probability) and each run of the hedge stage before the
confirmation (the early belief, the hedge target and its checked move: ``Hedger.belief``,
``target`` and ``plan``, what ``HedgeStage.on_belief`` computes). Ruckig trajectories are kept
as their solver inputs and solved again on replay (Ruckig is deterministic).

``replay`` (any checkout, by ``PYTHONPATH``; a checkout without the hedge stage replays the
choices alone) times every call ``--repeat`` times with ``time.thread_time_ns`` (CPU time of
this thread: another process's load slows it much less than the wall clock) and prints the
times and each choice's option values (so two checkouts can be checked to choose alike, bit for
bit). With ``--profile`` it counts Python-level calls per decision instead (cProfile: load
independent); under ``valgrind --tool=callgrind`` with ``--limit`` it gives instruction counts.

``compare`` records with this checkout, then alternates ``replay`` subprocesses of the old
checkout (``--old``, its ``PYTHONPATH``) and this one for ``--rounds`` rounds, and prints per
code the p50, p99 and max over the calls of each call's median CPU time, their ratios new/old,
and whether every option value is equal.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if not os.environ.get("PYTHONPATH"):  # PYTHONPATH may name another checkout to measure
    sys.path.insert(0, str(ROOT))

from decision_record import CHOOSE, HEDGE, record  # noqa: E402  (bench/, the script's dir)


# ---------------------------------------------------------------------------- replay
class Replayer:
    """Runs recorded calls with the code on ``sys.path`` (this checkout or ``PYTHONPATH``)."""

    def __init__(self, tree_path: str):
        from thinkfast.control.config import RunConfig
        from thinkfast.decide.choice import Chooser
        from thinkfast.decide.tree_view import runtime_tree
        from thinkfast.robot.model import load_robot
        from thinkfast.robot.steering import Steering
        from thinkfast.tree.file import load_tree

        cfg, robot = RunConfig(), load_robot()
        self.tree = runtime_tree(load_tree(Path(tree_path)), robot, cfg)
        self.Steering = Steering
        steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
        t = self.tree
        self.chooser = Chooser(
            t.goal_q, t.goal_yz, robot, t.plane_x, t.ball_radius, steer, cfg.choice, cfg.path_value
        )
        self._steers: dict = {}
        self.hedger = None
        try:
            from thinkfast.control.hedge import Hedger
        except ImportError:  # a checkout without the hedge stage
            return
        self.hedger = Hedger(
            t, robot, steer, cfg.hedge, cfg.early, cfg.filter.gravity, cfg.execution.controller_lag
        )

    def trajectory(self, spec):
        """The Ruckig trajectory of recorded solver inputs (None for None)."""
        if spec is None:
            return None
        limits, state, target = spec
        key = tuple(map(tuple, limits))
        if key not in self._steers:
            self._steers[key] = self.Steering(*limits)
        return self._steers[key].to_rest(state, target)

    def prepare(self, call):
        """A zero-argument function that makes the decision of ``call`` (or None: not here)."""
        kind, args, seg, _ = call
        if kind == CHOOSE:
            t0, end, spec = seg
            current = _Current(t0, self.trajectory(spec), end)
            return lambda: self.chooser.choose(*args, current)
        if self.hedger is None:
            return None
        t_now, stamp, points, state = args
        h = self.hedger

        def hedge():
            fit, c = h.belief(points)
            if fit is not None:
                return h.plan(state, h.target(c, stamp, t_now), t_now)
            return None

        return hedge


class _Current:
    """The segment in progress as the chooser reads it."""

    def __init__(self, t0, traj, end):
        self.t0, self.traj, self.end = t0, traj, end


def replay(calls_path: Path, repeat: int, limit: int | None, kind: str | None = None) -> dict:
    """CPU time [ns] of every call (of ``kind``, the first ``limit``), ``repeat`` times (calls
    in recorded order each time), and each decision's outcome."""
    with open(calls_path, "rb") as f:
        rec = pickle.load(f)
    rp = Replayer(rec["tree"])
    calls = [c for c in rec["calls"] if kind is None or c[0] == kind][:limit]
    fns = [rp.prepare(c) for c in calls]
    values = []
    for c, fn in zip(calls, fns, strict=True):  # once untimed: warm and check
        values.append(_outcome(c[0], None if fn is None else fn()))
    gc.collect()
    gc.freeze()  # as the daemon's planner does at start
    times = np.full((len(calls), repeat), -1, dtype=np.int64)
    clock = time.thread_time_ns
    for r in range(repeat):
        for i, fn in enumerate(fns):
            if fn is None:
                continue
            t0 = clock()
            fn()
            times[i, r] = clock() - t0
    return {
        "kinds": [c[0] for c in calls],
        "times_ns": times.tolist(),
        "values": values,
        "recorded_values": [c[3] for c in calls],
    }


def _outcome(kind: str, out) -> list | None:
    """What a decision returned, comparable across checkouts: the option values of a choice,
    the target and duration of a hedge move (None: none)."""
    if out is None:
        return None
    if kind == CHOOSE:
        return [o.value for o in out[1]]
    return [*map(float, out.end[:3]), float(out.traj.duration)]


def profile(calls_path: Path, limit: int | None) -> dict:
    """Python-level function calls (cProfile) per decision, by kind, and the top functions."""
    import cProfile
    import pstats

    with open(calls_path, "rb") as f:
        rec = pickle.load(f)
    rp = Replayer(rec["tree"])
    calls = rec["calls"][:limit]
    fns = [rp.prepare(c) for c in calls]
    for fn in fns:
        if fn is not None:
            fn()
    out = {}
    for kind in (CHOOSE, HEDGE):
        todo = [fn for c, fn in zip(calls, fns, strict=True) if c[0] == kind and fn is not None]
        if not todo:
            continue
        prof = cProfile.Profile()
        prof.enable()
        for fn in todo:
            fn()
        prof.disable()
        st = pstats.Stats(prof)
        top = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:15]
        out[kind] = {
            "decisions": len(todo),
            "calls_per_decision": round(st.total_calls / len(todo), 1),
            "top_tottime": [
                [
                    f"{Path(k[0]).name}:{k[2]}",
                    round(v[1] / len(todo), 2),
                    round(v[2] / st.total_tt, 3),
                ]
                for k, v in top
            ],
        }
    return out


# ---------------------------------------------------------------------------- compare
def summary(times_ns: list, kinds: list, kind: str | None) -> np.ndarray:
    """Per call, the median CPU time [ms] over every replay of it (calls of ``kind``)."""
    t = np.asarray(times_ns, dtype=float)
    keep = [i for i, k in enumerate(kinds) if (kind is None or k == kind) and t[i, 0] >= 0]
    return np.median(t[keep], axis=1) * 1e-6


def stats(ms: np.ndarray) -> dict:
    if len(ms) == 0:
        return {"calls": 0}
    return {
        "calls": int(len(ms)),
        "mean_ms": round(float(ms.mean()), 4),
        "p50_ms": round(float(np.percentile(ms, 50)), 4),
        "p99_ms": round(float(np.percentile(ms, 99)), 4),
        "max_ms": round(float(ms.max()), 4),
    }


def compare(args) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="decision_replay_"))
    calls = tmp / "calls.pkl"
    with open(calls, "wb") as f:
        pickle.dump(record(args.tree.resolve(), args.throws, args.seed), f)
    codes = {"old": str(Path(args.old).resolve()), "new": str(ROOT)}
    runs: dict[str, list] = {"old": [], "new": []}
    loads = [os.getloadavg()[0]]
    for _ in range(args.rounds):
        for name, path in codes.items():
            env = dict(os.environ, PYTHONPATH=path)
            cmd = [
                sys.executable,
                __file__,
                "replay",
                str(calls),
                "--repeat",
                str(args.repeat),
                "--raw",
            ]
            out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
            runs[name].append(json.loads(out.stdout))
            loads.append(os.getloadavg()[0])
    kinds = runs["new"][0]["kinds"]
    merged = {
        n: np.concatenate([np.asarray(r["times_ns"]) for r in rs], axis=1) for n, rs in runs.items()
    }
    result = {
        "tree": str(args.tree),
        "throws": args.throws,
        "seed": args.seed,
        "rounds": args.rounds,
        "repeat": args.repeat,
        "old": codes["old"],
        "choose_calls": kinds.count(CHOOSE),
        "hedge_calls": kinds.count(HEDGE),
    }
    old_v, new_v = runs["old"][0]["values"], runs["new"][0]["values"]
    result["same_values"] = all(
        a == b for a, b, k in zip(old_v, new_v, kinds, strict=True) if k == CHOOSE
    )
    recorded = runs["new"][0]["recorded_values"]
    result["values_as_recorded"] = all(
        a == b for a, b, k in zip(new_v, recorded, kinds, strict=True) if k == CHOOSE
    )
    rows = {}
    for name in ("old", "new"):
        for kind in (CHOOSE, HEDGE, None):
            ms = summary(merged[name].tolist(), kinds, kind)
            rows[f"{name} {kind or 'all'}"] = stats(ms)
    result["rows"] = rows
    result["max_single_ms"] = {  # the slowest single replay of any call
        n: round(float(merged[n].max()) * 1e-6, 4) for n in ("old", "new")
    }
    o, n = rows[f"old {CHOOSE}"], rows[f"new {CHOOSE}"]
    result["ratio_choose"] = {k: round(n[k] / o[k], 3) for k in ("p50_ms", "p99_ms", "max_ms")}
    na = rows["new all"]
    result["ratio_all_new_over_old_choose"] = {
        k: round(na[k] / o[k], 3) for k in ("p50_ms", "p99_ms", "max_ms")
    }
    if rows[f"new {HEDGE}"]["calls"]:
        result["hedge_over_choose_p99"] = round(rows[f"new {HEDGE}"]["p99_ms"] / n["p99_ms"], 3)
    per_call = summary(merged["new"].tolist(), kinds, CHOOSE) / summary(
        merged["old"].tolist(), kinds, CHOOSE
    )
    result["per_call_ratio_median"] = round(float(np.median(per_call)), 3)
    result["load_average_1min"] = [round(x, 2) for x in loads]
    from thinkfast.machine import machine_info

    result["machine"] = machine_info()
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="record the decision calls of simulated throws")
    r.add_argument("--tree", type=Path, default=ROOT / "trees" / "irb1600_default.h5")
    r.add_argument("--throws", type=int, default=60)
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--out", type=Path, required=True)
    p = sub.add_parser("replay", help="time recorded calls with the code on the path")
    p.add_argument("calls", type=Path)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--limit", type=int, default=None, help="the first N calls only")
    p.add_argument("--kind", choices=(CHOOSE, HEDGE), help="calls of this kind only")
    p.add_argument("--profile", action="store_true", help="cProfile call counts instead")
    p.add_argument("--raw", action="store_true", help="print the raw JSON (for compare)")
    p.add_argument("--json", action="store_true")
    c = sub.add_parser("compare", help="record, then replay old and new alternately")
    c.add_argument("--old", required=True, help="checkout of the old code")
    c.add_argument("--tree", type=Path, default=ROOT / "trees" / "irb1600_default.h5")
    c.add_argument("--throws", type=int, default=60)
    c.add_argument("--seed", type=int, default=1)
    c.add_argument("--rounds", type=int, default=4)
    c.add_argument("--repeat", type=int, default=3)
    c.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    if args.cmd == "record":
        rec = record(args.tree.resolve(), args.throws, args.seed)
        with open(args.out, "wb") as f:
            pickle.dump(rec, f)
        kinds = [c[0] for c in rec["calls"]]
        print(f"{len(kinds)} calls: {kinds.count(CHOOSE)} choices, {kinds.count(HEDGE)} hedge")
        return 0
    if args.cmd == "replay":
        if args.profile:
            print(json.dumps(profile(args.calls, args.limit), indent=None if args.json else 1))
            return 0
        out = replay(args.calls, args.repeat, args.limit, args.kind)
        if args.raw:
            print(json.dumps(out))
            return 0
        res = {
            k or "all": stats(summary(out["times_ns"], out["kinds"], k))
            for k in (CHOOSE, HEDGE, None)
        }
        res["load_average"] = [round(x, 2) for x in os.getloadavg()]
        print(json.dumps(res, indent=None if args.json else 1))
        return 0
    res = compare(args)
    if args.json:
        print(json.dumps(res))
        return 0
    print(
        f"decision calls replayed: {res['choose_calls']} choices, {res['hedge_calls']} hedge "
        f"({res['throws']} throws, seed {res['seed']}), {res['rounds']} rounds x "
        f"{res['repeat']} alternating old/new; CPU time per call, median of its replays"
    )
    print(f"  {'code':>12} {'calls':>6} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    for name, row in res["rows"].items():
        if row["calls"]:
            print(
                f"  {name:>12} {row['calls']:>6} {row['p50_ms']:>8.3f} {row['p99_ms']:>8.3f} "
                f"{row['max_ms']:>8.3f}"
            )
    print(
        f"  new/old choose: {res['ratio_choose']}; per call median {res['per_call_ratio_median']}"
    )
    print(f"  new (choices and hedge) / old choices: {res['ratio_all_new_over_old_choose']}")
    if "hedge_over_choose_p99" in res:
        print(f"  hedge p99 / choose p99 (new): {res['hedge_over_choose_p99']}")
    print(f"  slowest single replay [ms]: {res['max_single_ms']}")
    print(f"  same option values old and new: {res['same_values']}")
    print(f"  load average (1 min) over the run: {res['load_average_1min']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
