"""The campaign: every scenario in order, one line each, or one JSON object.

from bench.faultkit.campaign import make_context, run_campaign
results = run_campaign(make_context(tree), ["malformed", "sigint"], Options())
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

from bench.faultkit import sc_egm, sc_motion, sc_process, sc_record  # noqa: F401 (register)
from bench.faultkit.cell import Context
from bench.faultkit.scenario import REGISTRY, Options, Result

ORDER = (
    "malformed", "duplicated", "second_sender", "flood", "absurd_feedback", "seqno_reset",
    "silence_rest", "silence_motion", "arm_stops_following", "sigint", "sigterm",
    "zenoh_peer_lost", "record_missing", "record_readonly", "record_full", "fuzz_detections",
    "baseline_tree", "baseline_naive", "pauses_tree", "pauses_naive", "soft_servo_tree",
    "soft_servo_naive", "clock_jitter",
)  # fmt: skip
assert set(ORDER) == set(REGISTRY), set(ORDER) ^ set(REGISTRY)

# figures worth a place on a scenario's line, besides the ones it adds itself
_LINE = ("answered_pct", "missed_unexplained", "v_ratio", "a_ratio", "jerk_ratio_brake",
         "resync_pos_err_mrad", "resync_vel_ratio")  # fmt: skip
_COMMON = set(_LINE) | {
    "cycles", "missed", "missed_host_stall", "host_stall_max_ms", "a_ratio_all", "speedref_ratio",
    "speedref_jerk_ratio_brake", "jerk_ratio_normal", "resyncs_checked", "resyncs_late", "gaps",
    "brake_cycles", "extra_replies", "nonfinite", "outside_urdf", "bad_replies",
    "resync_failures",
}  # fmt: skip


def make_context(tree: Path, seed: int = 1, daemon_opts=(), log=print) -> Context:
    """The shared context: the default robot, its kinematics, the default camera pose."""
    from thinkfast.control.config import load_run_config
    from thinkfast.robot.kinematics import Kinematics
    from thinkfast.robot.model import default_robot_path, load_robot
    from thinkfast.sim.camera import CameraModelConfig

    robot = load_robot(default_robot_path())
    return Context(Path(tree), robot, Kinematics(robot), load_run_config(None).camera,
                   CameraModelConfig(), seed, tuple(daemon_opts), log)  # fmt: skip


def run_campaign(ctx: Context, names, opts: Options, on_result=None) -> list[Result]:
    """Run scenarios ``names`` in campaign order (then the soak when ``opts.soak_minutes``)."""
    results = []
    for name in [n for n in ORDER if n in names]:
        r = REGISTRY[name][0](ctx, opts)
        results.append(r)
        if on_result is not None:
            on_result(r)
    if opts.soak_minutes > 0:
        r = sc_record.soak(ctx, opts, opts.soak_minutes)
        results.append(r)
        if on_result is not None:
            on_result(r)
    return results


def _short(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_short(x)}" for k, x in list(v.items())[:6]) + "}"
    if isinstance(v, list) and len(v) > 4:
        return f"[{len(v)} items]"
    return str(v)


def line(r: Result) -> str:
    """One line: name, PASS/FAIL/ERROR, seconds, the scenario's figures, what failed."""
    verdict = {True: "PASS", False: "FAIL", None: "ERROR"}[r.passed]
    own = [k for k in r.figures if k not in _COMMON and not k.startswith("daemon_")]
    keys = [k for k in _LINE if r.figures.get(k) is not None] + own
    figs = "; ".join(f"{k} {_short(r.figures[k])}" for k in keys)
    why = f"  <- {'; '.join(r.failures)}" if r.failures else ""
    return f"{r.name:<22} {verdict:<5} {r.seconds:6.1f} s  {figs}{why}"


def as_json(results: list[Result], started: float) -> str:
    """One JSON object: every scenario's verdict, figures and failures, plus the machine."""
    out = {
        "runtime_s": round(time.time() - started, 1),
        "passed": sum(r.passed is True for r in results),
        "failed": sum(r.passed is False for r in results),
        "errors": sum(r.passed is None for r in results),
        "machine": {
            "platform": platform.platform(),
            "cores": os.cpu_count(),
            "load_avg": [round(x, 2) for x in os.getloadavg()],
        },  # fmt: skip
        "scenarios": {
            r.name: {
                "passed": r.passed,
                "seconds": r.seconds,
                "failures": r.failures,
                "figures": r.figures,
            }
            for r in results
        },  # fmt: skip
    }
    return json.dumps(out, default=_plain)


def _plain(v):
    try:
        import numpy as np

        if isinstance(v, np.generic):
            return v.item()
        if isinstance(v, np.ndarray):
            return v.tolist()
    except ImportError:
        pass
    return str(v)
