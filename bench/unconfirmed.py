"""Real flights never confirmed: per throw, what the launch gate and the hedge stage did.

Flies the bench's throws (the same throws and camera noise as ``thinkfast-sim bench``: throw
``i`` of the seed uses :func:`thinkfast.sim.bench.throw_seed`) through the lockstep's control
core with the ``tree`` planner's executor (the gate, the launch detector and the hedge stage are
the daemon's; the tree planner and naive share the gate, so a throw one never confirms the other
never confirms either). Each throw is flown until it is confirmed (what follows is the
planner's) or, unconfirmed, until its crossing plus ``after_crossing``. Per throw it writes one
JSON line: kind, flight time, crossing, when the launch detector declared the launch and when
the throw was confirmed (after release [s]; null: never), and every hedge: start, end, why
(``no_launch``, ``timeout``, ``silence``, ``confirmed``). ``summary`` counts, by kind:

- ``unconfirmed``: real flights (not feints) the gate never confirmed;
- ``no_launch_detector``: real flights the launch detector never declared (the gate's own count
  may still have confirmed them, late);
- ``no_launch_in_flight``: hedges that ended ``no_launch`` after the release of a real flight,
  and the throws with one.

    python bench/unconfirmed.py run --tree trees/irb1600_default.h5 --throws 1000 --seed 1 \\
        --start 0 --stop 250 --out rows/u_000.jsonl
    python bench/unconfirmed.py summary rows/u_*.jsonl [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from thinkfast.control.config import load_run_config
from thinkfast.control.link import Feedback
from thinkfast.estimate import early_belief as eb
from thinkfast.sim.bench import throw_seed
from thinkfast.sim.camera import detection_payload, observe_cameras
from thinkfast.sim.cli import _throws, _WorldFactory
from thinkfast.sim.controller import SimController
from thinkfast.sim.lockstep import DT, LEAD
from thinkfast.sim.throws import plane_crossing

KEYS = ("throws", "unconfirmed", "no_launch_detector", "no_launch_in_flight",
        "throws_with_no_launch_in_flight", "no_launch_while_held", "no_launch_cause")  # fmt: skip


def fly(world, throw, seed: int, planner: str = "tree") -> dict:
    """The gate's and the hedge stage's record of one throw (module doc)."""
    cfg, robot = world.cfg, world.robot
    t_rel = LEAD + throw.t_release
    dets = observe_cameras(throw, world.cameras, seed, t_rel)
    feint = throw.kind == "feint"
    if feint:
        cross, t_end = None, t_rel + 2.2
    else:
        cross = plane_crossing(throw)
        t_end = t_rel + cross.t + cfg.throw.after_crossing + 0.15
    ex = world.parts.executor(planner)
    core = world.parts.core(ex)
    sim = SimController(world.servo, q0=robot.home)
    launch_at = confirmed_at = math.nan
    hedges: list[dict] = []
    stage = ""

    def watch(t: float) -> None:
        nonlocal launch_at, stage
        if math.isnan(launch_at) and ex.gate.launch.launches:
            launch_at = ex.gate.t_last_det - t_rel  # capture time of the declaring detection
        if ex.stage == "hedge" and stage != "hedge":
            hedges.append({"start": round(t - t_rel, 4), "end": None, "why": ""})
        elif stage == "hedge" and ex.stage != "hedge":
            why = ex.hedge_end
            cause = _cause(ex) if why == "no_launch" else ""
            hedges[-1].update(end=round(t - t_rel, 4), why=why, cause=cause)
        stage = ex.stage

    k, t = 0, 0.0
    while t <= t_end and math.isnan(confirmed_at):
        while k < len(dets) and dets[k].delivery_time <= t:
            core.on_detection(detection_payload(dets[k]), None, t)
            k += 1
            watch(t)
        reply = core.on_feedback(Feedback(round(t * 1000.0), sim.q), t)
        watch(t)
        if not math.isnan(ex.episode.t_confirmed):
            confirmed_at = ex.episode.t_confirmed - t_rel
        if reply is not None:
            sim.command(reply.q, reply.qd, t)
        sim.step(DT)
        t += DT
    flown = [d for d in dets if d.capture_stamp > t_rel and d.delivery_time <= t]
    return {
        "throw_id": throw.id,
        "kind": throw.kind,
        "flight_time": round(float(throw.flight_time), 4),
        "crossing_y": None if cross is None else round(float(cross.y), 4),
        "crossing_z": None if cross is None else round(float(cross.z), 4),
        "release_x": round(float(throw.p_release[0]), 4),
        "launch": None if math.isnan(launch_at) else round(launch_at, 4),
        "confirmed": None if math.isnan(confirmed_at) else round(confirmed_at, 4),
        "flight_detections": len(flown),
        "hedges": hedges,
    }


def _cause(ex) -> str:
    """Why the early belief made no launch likely: ``run`` (fewer than ``trigger_points`` of
    the newest detections left the hold), ``fit`` (its chi-square over the limit: a gross
    outlier among them, most often) or ``crossing`` (none predicted)."""
    h = ex.hedge.hedger
    fit = eb.early_fit(list(ex.gate.launch.points), h.early, h.tree.plane_x, h.yz_lo, h.yz_hi,
                       h.gravity)  # fmt: skip
    if fit is None or fit.left < h.early.trigger_points:
        return "run"
    return "fit" if not eb.likely_launch(fit, h.early) else "crossing"


def _run(a) -> None:
    cfg = load_run_config(a.config)
    balls = _throws(a.throws, a.seed, None, a.mix, a.throws // 10 if a.feints < 0 else a.feints)
    stop = len(balls) if a.stop is None else min(a.stop, len(balls))
    world = _WorldFactory(Path(a.tree), cfg)()
    with open(a.out, "w", encoding="utf-8") as f:
        for i in range(a.start, stop):
            f.write(json.dumps(fly(world, balls[i], throw_seed(a.seed, i))) + "\n")
            f.flush()
    print(f"throws {a.start}..{stop - 1} -> {a.out}")


def summarize(rows: list[dict]) -> dict:
    """Counts by kind (module doc), and the unconfirmed flights themselves."""
    out: dict = {k: Counter() for k in KEYS}
    listed = []
    for r in rows:
        kind = r["kind"]
        out["throws"][kind] += 1
        flight = kind != "feint"
        in_flight = [h for h in r["hedges"] if h["why"] == "no_launch" and h["end"] >= 0.0]
        out["no_launch_while_held"][kind] += sum(
            h["why"] == "no_launch" and h["end"] < 0.0 for h in r["hedges"]
        )
        if not flight:
            continue
        out["unconfirmed"][kind] += r["confirmed"] is None
        out["no_launch_detector"][kind] += r["launch"] is None
        out["no_launch_in_flight"][kind] += len(in_flight)
        for h in in_flight:
            out["no_launch_cause"][h.get("cause") or "?"] += 1
        out["throws_with_no_launch_in_flight"][kind] += bool(in_flight)
        if r["confirmed"] is None or in_flight:
            listed.append(r)
    summary = {k: dict(sorted(v.items())) for k, v in out.items()}
    delays = [r["confirmed"] for r in rows if r["kind"] != "feint" and r["confirmed"] is not None]
    summary["confirmed_median_ms"] = round(1e3 * float(np.median(delays)), 1) if delays else None
    summary["listed"] = listed
    return summary


def _summary(a) -> None:
    rows = []
    for p in sorted(a.rows):
        with open(p, encoding="utf-8") as f:
            rows += [json.loads(line) for line in f if line.strip()]
    s = summarize(rows)
    if a.json:
        print(json.dumps(s))
        return
    for key in KEYS:
        print(f"{key:32s} {s[key]}")
    print(f"{'confirmed (median, after release)':32s} {s['confirmed_median_ms']} ms")
    for r in s["listed"]:
        hedges = ", ".join(f"{h['start']:+.3f}..{h['end']:+.3f} {h['why']}" for h in r["hedges"])
        print(f"  {r['throw_id']:10s} {r['kind']:6s} T {r['flight_time']:.3f} s at "
              f"({r['crossing_y']:+.2f}, {r['crossing_z']:.2f}) from x {r['release_x']:.2f}: "
              f"launch {r['launch']} confirmed {r['confirmed']}; "
              f"hedges {hedges or '-'}")  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="fly throws start..stop-1 of the bench's set")
    r.add_argument("--tree", required=True)
    r.add_argument("--throws", type=int, default=1000)
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--mix", default=None)
    r.add_argument("--feints", type=int, default=-1, help="default: a tenth of --throws")
    r.add_argument("--config", default=None)
    r.add_argument("--start", type=int, default=0)
    r.add_argument("--stop", type=int, default=None)
    r.add_argument("--out", required=True)
    s = sub.add_parser("summary", help="count the rows by kind")
    s.add_argument("rows", nargs="+")
    s.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    (_run if a.cmd == "run" else _summary)(a)


if __name__ == "__main__":
    sys.exit(main())
