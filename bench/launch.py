"""Launch detector: false launches on held balls and time from release to launch.

Balls are held ``--hold`` seconds each and then thrown; the camera model (its default outliers,
or pure-depth outliers at ``--outlier-prob`` with ``--depth-only``) observes them. For every ball,
detections are fed in capture order to the runtime's launch detector; a launch declared while the
ball is still held is a false launch (the detector is reset and goes on), the first one after
the release gives the delay (capture time of the detection that declared it, after release; the
detection reaches the daemon 30-60 ms later).

The hedge stage's trigger (``[early]``, :func:`thinkfast.estimate.early_belief.likely_launch` on
the same detections) is counted beside it: hedges begun while the ball is held (each time the
test turns true), per minute of holding, and the delay from release to the first one after it.
With ``--executor N``, the first N balls are also flown through the tree planner's executor
(``--hedge`` mode, default mean; detections delivered with the camera's latency, a setpoint
every 4 ms, until the release): the largest shield displacement from home its commanded joints
reach while the ball is held.

    python bench/launch.py                       # 100 balls held 5 s: 25,000 held frames
    python bench/launch.py --depth-only --outlier-prob 0.04 --json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from thinkfast.control.config import RunConfig, load_run_config
from thinkfast.estimate import early_belief as eb
from thinkfast.estimate.launch import LaunchDetector
from thinkfast.machine import machine_info
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.cli import _throw_config
from thinkfast.sim.throws import sample_throws
from thinkfast.tree.file import load_tree
from thinkfast.tree.provenance import Provenance

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--balls", type=int, default=100)
    ap.add_argument("--hold", type=float, default=5.0, help="seconds each ball is held")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--outlier-prob", type=float, default=None, help="camera outlier rate")
    ap.add_argument("--depth-only", action="store_true", help="outliers along the ray only")
    ap.add_argument("--config", help="runtime config (TOML): its [launch] table is tested")
    ap.add_argument("--tree", default=str(DEFAULT_TREE), help="plane and goal grid (hedge prior)")
    ap.add_argument("--mix", default=None, help="kinds of throw, KIND=WEIGHT,... (default mix)")
    ap.add_argument("--executor", type=int, default=0, help="balls flown through the executor")
    ap.add_argument("--hedge", default="mean", help="[hedge] mode of the executor (--executor)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    cfg = RunConfig() if args.config is None else load_run_config(args.config)
    cam = CameraModelConfig()
    if args.outlier_prob is not None:
        cam = dataclasses.replace(cam, outlier_prob=args.outlier_prob)
    if args.depth_only:
        cam = dataclasses.replace(cam, outlier_lateral=0.0)
    rot, pos = cfg.camera.rotation(), cfg.camera.translation()
    tcfg = dataclasses.replace(_throw_config(args.mix), hold_time=(args.hold, args.hold))
    throws = sample_throws(tcfg, args.balls, args.seed)
    tree = load_tree(args.tree)
    plane = (Provenance.of(tree.meta).plane_x, tree.goal_yz.min(axis=0), tree.goal_yz.max(axis=0))
    held, false_launches, delays, missed = 0, 0, [], 0
    hedges, hedge_delays = 0, []
    for i, th in enumerate(throws):
        dets = observe(th, cam, cfg.camera, np.random.default_rng(args.seed * 1000 + i), 0.0)
        det = LaunchDetector(cfg.launch, cfg.filter, cfg.camera.xyz)
        launched, likely, hedged = False, False, False
        for d in sorted(dets, key=lambda d: d.capture_stamp):
            held += d.capture_stamp < 0.0
            fit = det.add(d.capture_stamp, rot @ d.position_camera + pos)
            was, likely = likely, _likely(det, cfg, plane)
            if likely and not was and d.capture_stamp < 0.0:
                hedges += 1
            if likely and not hedged and d.capture_stamp >= 0.0:
                hedge_delays.append(d.capture_stamp)
                hedged = True
            if fit is None:
                continue
            if d.capture_stamp < 0.0:
                false_launches += 1
                det.reset()
                continue
            delays.append(d.capture_stamp)
            launched = True
            break
        missed += not launched
    out = {
        "balls": args.balls,
        "held_frames": int(held),
        "false_launches": false_launches,
        "launched": len(delays),
        "not_launched": missed,
        "delay_median_ms": round(1e3 * float(np.median(delays)), 1),
        "delay_p90_ms": round(1e3 * float(np.percentile(delays, 90)), 1),
        "held_shield_displacement_max_m": _held_displacement(
            throws[: args.executor],
            dataclasses.replace(cfg, hedge=dataclasses.replace(cfg.hedge, mode=args.hedge)),
            cam,
            tree,
            args.seed,
        ),
        "hedges_while_held": hedges,
        "hedges_per_minute_held": round(hedges / (held / cam.rate / 60.0), 2),
        "hedge_delay_median_ms": round(1e3 * float(np.median(hedge_delays)), 1),
        "hedge_delay_p90_ms": round(1e3 * float(np.percentile(hedge_delays, 90)), 1),
        "outlier_prob": cam.outlier_prob,
        "depth_only": args.depth_only,
        "machine": machine_info(),
    }
    if args.json:
        print(json.dumps(out))
        return
    print(f"{args.balls} balls held {args.hold:g} s ({held} held frames), outliers "
          f"{cam.outlier_prob:g}{' along the ray only' if args.depth_only else ''}")  # fmt: skip
    print(f"false launches  {false_launches}")
    print(f"launched        {len(delays)} / {args.balls}")
    print(
        f"release -> launch (capture time): median {out['delay_median_ms']} ms, "
        f"p90 {out['delay_p90_ms']} ms"
    )
    if out["held_shield_displacement_max_m"] is not None:
        print(f"executor        shield displacement while held: max "
              f"{out['held_shield_displacement_max_m']:.3f} m ({args.executor} balls)")  # fmt: skip
    print(
        f"hedge trigger   {hedges} while held ({out['hedges_per_minute_held']} per minute of "
        f"holding); release -> first after release: median {out['hedge_delay_median_ms']} ms, "
        f"p90 {out['hedge_delay_p90_ms']} ms"
    )


def _held_displacement(throws, cfg: RunConfig, cam, tree, seed: int) -> float | None:
    """Largest shield-centre distance from home [m] the executor commands while the balls are
    held (None: no ball flown)."""
    if not throws:
        return None
    from thinkfast.control.executor import Executor
    from thinkfast.decide.tree_view import runtime_tree
    from thinkfast.robot.model import load_robot
    from thinkfast.robot.shield_path import ShieldSampler

    robot = load_robot(None)
    rt = runtime_tree(tree, robot, cfg)
    sampler = ShieldSampler(robot)
    home = sampler.centres(robot.home[:3])
    rot, pos = cfg.camera.rotation(), cfg.camera.translation()
    worst = 0.0
    for i, th in enumerate(throws):
        dets = observe(th, cam, cfg.camera, np.random.default_rng(seed * 1000 + i), 0.0)
        dets = sorted(dets, key=lambda d: d.delivery_time)
        ex = Executor(rt, robot, cfg, "tree")
        ex.start_from(robot.home, dets[0].delivery_time - 0.004)
        t, k = dets[0].delivery_time, 0
        while t < 0.0:  # until the release (at 0)
            while k < len(dets) and dets[k].delivery_time <= t:
                d = dets[k]
                ex.on_detection(t, d.capture_stamp, rot @ d.position_camera + pos)
                k += 1
            q, _ = ex.setpoint(t)
            worst = max(worst, float(np.linalg.norm(sampler.centres(q[:3]) - home)))
            t += 0.004
    return worst


def _likely(det: LaunchDetector, cfg: RunConfig, plane) -> bool:
    """The hedge stage's trigger on the detector's detections (``[early]``)."""
    fit = eb.early_fit(
        list(det.points), cfg.early, plane[0], plane[1], plane[2], cfg.filter.gravity
    )
    return eb.likely_launch(fit, cfg.early)


if __name__ == "__main__":
    main()
