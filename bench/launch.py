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
The default camera runs in the run config's ``[camera] mode`` and at its ``fps``, and the launch
detector fits as the throw gate's does (the mode's stereo model, ``launch_window`` detections at
that rate).
With ``--executor N``, the first N balls are also flown through the tree planner's executor
(``--hedge`` mode, default mean; detections delivered with the camera's latency, a setpoint
every 4 ms, until the release): the largest shield displacement from home its commanded joints
reach while the ball is held.

With ``--cameras`` (as ``thinkfast-sim bench --cameras``, docs/CAMERAS.md) every camera named
observes the balls and the detections go, in delivery order, through the daemon's intake and
throw gate (camera check, filter, the launch detector with ``[fusion] launch_window``), as in
the daemon, and every belief is counted by the gate's confirmation as in the executor:
``false_confirmations`` counts the throws the gate confirmed while the ball was held (by the
launch detector or by its count). Without it the default camera's detections are fed to the
launch detector in capture order (the same detections, one camera: the same order).

    python bench/launch.py                       # 100 balls held 5 s: 25,000 held frames
    python bench/launch.py --depth-only --outlier-prob 0.04 --json
    python bench/launch.py --cameras base,side --mix still=1 --executor 100 --json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from thinkfast.control.config import (
    RunConfig,
    default_camera_filter,
    early_config,
    launch_window,
    load_run_config,
)
from thinkfast.estimate import early_belief as eb
from thinkfast.estimate.launch import LaunchDetector
from thinkfast.machine import machine_info
from thinkfast.sim.camera import (
    CameraModelConfig,
    detection_payload,
    mode_model,
    observe,
    observe_cameras,
)
from thinkfast.sim.cli import _throw_config, with_cameras
from thinkfast.sim.lockstep import sim_cameras
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
    ap.add_argument("--cameras", default=None, help="e.g. base,side (default: the run config's)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    cfg = RunConfig() if args.config is None else load_run_config(args.config)
    cfg = with_cameras(cfg, args.cameras)
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
    hedges, hedge_delays, held_s, false_confirmations = 0, [], 0.0, 0
    rt = _runtime_tree(tree, cfg)[0] if cfg.cameras else None
    rate = mode_model(cfg.camera, cam).rate  # the default camera's frames per second
    for i, th in enumerate(throws):
        feed = _GateFeed(rt, cfg) if cfg.cameras else None
        det = feed.launch if feed else _detector(cfg)
        launched, likely, hedged = False, False, False
        for d in _detections(th, cfg, cam, args.seed * 1000 + i):
            t = d.capture_stamp - _wall(cfg)  # after the release [s]
            held_s += (d.camera is None and t < 0.0) / rate
            if feed is None:
                fit = det.add(d.capture_stamp, rot @ d.position_camera + pos)
            else:
                fit = feed(d, t < 0.0)
                if fit is False:
                    continue  # not fused (not new, or its camera not yet trusted)
            held += t < 0.0
            was, likely = likely, _likely(det, cfg, plane)
            if likely and not was and t < 0.0:
                hedges += 1
            if likely and not hedged and t >= 0.0:
                hedge_delays.append(t)
                hedged = True
            if fit is None:
                continue
            if t < 0.0:
                false_launches += 1
                det.reset()
                continue
            delays.append(t)
            launched = True
            break
        missed += not launched
        false_confirmations += feed.false_confirmations if feed else 0
    out = {
        "balls": args.balls,
        "held_frames": int(held),
        "false_launches": false_launches,
        "false_confirmations": false_confirmations if cfg.cameras else None,
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
        "hedges_per_minute_held": round(hedges / (held_s / 60.0), 2),
        "hedge_delay_median_ms": round(1e3 * float(np.median(hedge_delays)), 1),
        "hedge_delay_p90_ms": round(1e3 * float(np.percentile(hedge_delays, 90)), 1),
        "cameras": ["base", *(c.id for c in cfg.cameras)],
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
    if cfg.cameras:
        print(f"gate: throws confirmed while held {false_confirmations}")
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
    from thinkfast.control.intake import Intake
    from thinkfast.robot.shield_path import ShieldSampler

    rt, robot = _runtime_tree(tree, cfg)
    sampler = ShieldSampler(robot)
    home = sampler.centres(robot.home[:3])
    rot, pos = cfg.camera.rotation(), cfg.camera.translation()
    worst = 0.0
    for i, th in enumerate(throws):
        dets = sorted(_detections(th, cfg, cam, seed * 1000 + i), key=lambda d: d.delivery_time)
        ex = Executor(rt, robot, cfg, "tree")
        ex.start_from(robot.home, dets[0].delivery_time - 0.004)
        intake = Intake(cfg.camera, cfg.detections, cfg.cameras)
        t, k = dets[0].delivery_time, 0
        while t < _wall(cfg):  # until the release
            while k < len(dets) and dets[k].delivery_time <= t:
                d = dets[k]
                if not cfg.cameras:
                    ex.on_detection(t, d.capture_stamp, rot @ d.position_camera + pos)
                elif (acc := intake.take(detection_payload(d), None)) is not None:
                    ex.on_detection(t, acc.stamp, acc.position, acc.camera)
                k += 1
            q, _ = ex.setpoint(t)
            worst = max(worst, float(np.linalg.norm(sampler.centres(q[:3]) - home)))
            t += 0.004
    return worst


def _wall(cfg: RunConfig) -> float:
    """Release time on the detections' clock [s]: the intake takes no negative stamp."""
    return 10.0 if cfg.cameras else 0.0


def _detections(th, cfg: RunConfig, cam: CameraModelConfig, seed: int) -> list:
    """Detections of one ball: the default camera's in capture order, or with ``[[cameras]]``
    every camera's in delivery order (the default camera's are the same either way), released
    at :func:`_wall`."""
    if not cfg.cameras:  # in [camera]'s mode and at its rate, as sim_cameras makes it
        model = mode_model(cfg.camera, cam)
        dets = observe(th, model, cfg.camera, np.random.default_rng(seed), 0.0)
        return sorted(dets, key=lambda d: d.capture_stamp)
    return observe_cameras(th, sim_cameras(cfg, cam), seed, _wall(cfg))


def _runtime_tree(tree, cfg: RunConfig):
    from thinkfast.decide.tree_view import runtime_tree
    from thinkfast.robot.model import load_robot

    robot = load_robot(None)
    return runtime_tree(tree, robot, cfg), robot


class _GateFeed:
    """A detection's way to the launch detector in the daemon: the intake, then the throw gate
    (camera check, filter, launch detector with ``[fusion] launch_window``), armed."""

    def __init__(self, rt, cfg: RunConfig):
        from thinkfast.control.gate import ThrowGate
        from thinkfast.control.intake import Intake

        self.gate = ThrowGate(rt, cfg)
        self.intake = Intake(cfg.camera, cfg.detections, cfg.cameras)
        self.launch = self.gate.launch
        self.false_confirmations = 0  # throws the gate confirmed while the ball was held

    def __call__(self, d, held: bool) -> bool | None:
        """True: ``d`` declared a launch; None: it did not; False: it was not fused. Each belief
        is counted by the gate's confirmation as in the executor (``held``: the ball is still
        in the hand, a confirmation is false; the gate then drops the throw)."""
        acc = self.intake.take(detection_payload(d), None)
        if acc is None:
            return False
        gate = self.gate
        fused = gate.fuse(acc.stamp, acc.position, acc.camera, armed=True)
        if not fused.ok:
            return False
        if gate.belief.n_meas >= 2 and gate.confirms(gate.crossing(), fused.launched, True):
            self.false_confirmations += held
            gate.drop()
        return True if fused.launched else None


def _detector(cfg: RunConfig) -> LaunchDetector:
    """The default camera's launch detector as the throw gate builds it: the stereo model of
    ``[camera]``'s mode and the fit's detections at its frame rate (``launch_window``)."""
    own = default_camera_filter(cfg)
    return LaunchDetector(cfg.launch, own, cfg.camera.xyz, 1, launch_window(cfg))


def _likely(det: LaunchDetector, cfg: RunConfig, plane) -> bool:
    """The hedge stage's trigger on the detector's detections (``[early]``; with several
    cameras as :func:`~thinkfast.control.config.early_config` makes it)."""
    early = early_config(cfg)
    fit = eb.early_fit(list(det.points), early, plane[0], plane[1], plane[2], cfg.filter.gravity)
    return eb.likely_launch(fit, early)


if __name__ == "__main__":
    main()
