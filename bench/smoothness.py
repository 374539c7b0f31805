"""Ordinary throws through the real daemon: how often the supervisor acts, and the motion the
controller applied, judged over the controller's own clock.

Starts ``thinkfast-run`` on loopback, runs the simulated controller (servo model, 250 Hz over
UDP) and throws N balls over zenoh, 3.5 s apart. Prints the daemon's intervention counts (ticks
where the supervisor changed a request or braked) and, from every command the controller
received, the largest finite-difference velocity, acceleration and jerk over the controller's
cycle (consecutive 4 ms cycles only), relative to the limits.

    python bench/smoothness.py --throws 200 [--planner tree] [--seed 7] [--json]
"""

from __future__ import annotations

import argparse
import json
import signal
import time
from pathlib import Path

import numpy as np

from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.control.config import RunConfig
from thinkfast.machine import machine_info
from thinkfast.robot.model import default_robot_path, load_robot
from thinkfast.sim import realtime as rt
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.controller_runner import ControllerRunner
from thinkfast.sim.publisher import publish_detections
from thinkfast.sim.throws import ThrowConfig, sample_throws

DT = 0.004


def applied_ratios(t: np.ndarray, q: np.ndarray, qd: np.ndarray, robot) -> dict:
    """Largest |finite difference| / limit over runs of consecutive cycles (controller time)."""
    ok1 = np.abs(np.diff(t) - DT) < 1e-9
    ok2 = ok1[1:] & ok1[:-1]
    ok3 = ok2[1:] & ok2[:-1]
    v = np.abs(np.diff(q, axis=0))[ok1] / DT / robot.v_max
    a = np.abs(np.diff(q, 2, axis=0))[ok2] / DT**2 / robot.a_max
    j = np.abs(np.diff(q, 3, axis=0))[ok3] / DT**3 / robot.j_max
    return {
        "cycles": int(len(t)),
        "gaps": int((~ok1).sum()),
        "velocity": float(v.max()),
        "acceleration": float(a.max()),
        "jerk": float(j.max()),
        "speed_ref": float((np.abs(qd) / robot.v_max).max()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--throws", type=int, default=20)
    ap.add_argument("--planner", default="tree")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--tree", type=Path, default=Path("trees/irb1600_default.h5"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    robot, cfg = load_robot(default_robot_path()), RunConfig()
    egm_port, zport = free_tcp_port(), free_tcp_port()
    proc = rt.start_daemon(args.tree, args.planner, egm_port, zport, "smooth", None, None)
    status: list[dict] = []
    try:
        rt.wait_port(proc, zport)
        sim = rt.WallClockSim(ServoConfig(), q0=robot.home)
        runner = ControllerRunner(sim, ("127.0.0.1", egm_port)).start()
        session = open_peer(connect=[f"tcp/127.0.0.1:{zport}"])
        session.declare_subscriber(
            "smooth/status", lambda s: status.append(json.loads(s.payload.to_bytes()))
        )
        time.sleep(1.0)
        t_start = time.time()
        for i, th in enumerate(sample_throws(ThrowConfig(), args.throws, args.seed)):
            rng = np.random.default_rng(args.seed * 100_003 + i)
            dets = observe(th, CameraModelConfig(), cfg.camera, rng, 0.0)
            t0 = time.time() + 0.3
            publish_detections(session, "smooth/detections", dets, t0_wall=t0)
            time.sleep(max(0.0, t0 + th.flight_time + rt.GAP - time.time()))
        runner.stop()
        runner.join(2.0)
        time.sleep(0.2)
        session.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
    cmds = sim.commands()
    last = status[-1]
    events = [
        line.split(" INFO ", 1)[1]
        for line in rt.daemon_log(proc).splitlines()
        if " INFO " in line and "throw_end" not in line
    ]
    out = {
        "machine": machine_info(),
        "throws": args.throws,
        "planner": args.planner,
        "minutes": round((time.time() - t_start) / 60, 1),
        "throws_seen": last["throws"],
        "interventions": last["interventions"],
        "intervention_share": last["interventions"]["intervened"] / last["interventions"]["ticks"],
        "safety": last["safety"],
        "faults": last["faults"],
        "egm": last["egm"],
        "applied": applied_ratios(cmds.t, cmds.q, cmds.qd, robot),
        "events": events,
    }
    if args.json:
        print(json.dumps(out))
        return
    iv, ap_ = out["interventions"], out["applied"]
    print(f"machine: {out['machine']}")
    print(f"{args.throws} throws ({args.planner}), {out['minutes']} min")
    print(f"{'supervisor ticks':28s} {iv['ticks']:>10d}")
    share = 100 * out["intervention_share"]
    print(f"{'ticks intervened':28s} {iv['intervened']:>10d}  ({share:.3f} %)")
    print(f"{'faults':28s} {out['faults']}")
    for k in ("velocity", "acceleration", "jerk", "speed_ref"):
        print(f"{'max applied ' + k + ' / limit':28s} {ap_[k]:>10.4f}")
    print(f"{'controller cycles (gaps)':28s} {ap_['cycles']:>10d} ({ap_['gaps']})")
    print("daemon events:", *events[:40], sep="\n  ")


if __name__ == "__main__":
    main()
