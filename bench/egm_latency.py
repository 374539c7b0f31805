"""EGM exchange latency on loopback: simulated controller (measuring side) <-> EGM sensor.

The measuring side is the simulated ABB controller of ``thinkfast.sim.controller``: each cycle
it sends an ``EgmRobot`` and times the ``EgmSensor`` reply (round trip on ``perf_counter``,
client send -> client receive). A cycle with no reply before the next one is ``missed``; a
reply that comes after its cycle is ``late``.

The server side runs in a separate process: by default this script starts itself with
``--serve`` (an ``EgmServer`` in a dedicated loop whose setpoints go through the safety
supervisor, as in the daemon); ``--target HOST:PORT`` measures any running sensor instead
(e.g. ``thinkfast-run``).

Rates: ``--rate 250`` (default) is the controller's real 4 ms cycle, so the default 10^5
exchanges take 400 s; ``--rate 0`` runs flat out (next request as soon as a reply is in, or
after a 4 ms time-out), which measures the same round trip in a fraction of the time but keeps
the server busier than a real controller would.

The first ``--warmup`` exchanges (default 250) are not counted. Round trips include any
scheduling delay of either process, so a loaded machine shows in the tail (``load_1min``).

    python bench/egm_latency.py --n 20000 --rate 0 --json
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import select
import subprocess
import sys
import time

import numpy as np

from thinkfast.errors import ThinkfastError
from thinkfast.runtime.egm_server import EgmServer, parse_hostport
from thinkfast.runtime.safety import SafetyConfig, SafetySupervisor, make_limits
from thinkfast.sim.controller import ControllerRunner, ServoConfig, SimController


def set_realtime(priority: int = 50) -> bool:
    """Put the calling thread under SCHED_FIFO (needs CAP_SYS_NICE); False if refused."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError):
        return False
    return True


def serve(bind: str, realtime: bool) -> None:
    """Server side: reply to every EgmRobot until stdin closes, then print counters as JSON."""
    servo = ServoConfig()
    cfg = SafetyConfig()
    limits = make_limits(
        servo.q_min, servo.q_max, servo.v_max, servo.a_max, [10 * a for a in servo.a_max],
        cfg.position_margin,
    )  # fmt: skip
    state: dict = {}

    def reply(fb):
        sup = state.get("sup")
        if sup is None:
            sup = state["sup"] = SafetySupervisor(limits, cfg, fb.q_rad)
            state["q0"], state["k"] = fb.q_rad.copy(), 0
        state["k"] += 1
        t = state["k"] * cfg.dt  # a slow sine on every joint: the supervisor passes it through
        q = state["q0"] + 0.2 * (1.0 - np.cos(2.0 * t))  # starts at rest
        cmd = sup.step(q, 0.4 * np.sin(2.0 * t) * np.ones(6), q_meas=fb.q_rad)
        return cmd.q, cmd.qd

    with EgmServer(bind, reply) as server:
        rt = set_realtime() if realtime else False
        gc.freeze()  # set-up objects out of the collector's way, as a daemon would
        print(f"PORT {server.address[1]} {int(rt)}", flush=True)
        fds = [server.fileno(), sys.stdin.fileno()]
        while True:
            ready, _, _ = select.select(fds, [], [], 1.0)
            if server.fileno() in ready:
                server.poll()
            if sys.stdin.fileno() in ready and not os.read(sys.stdin.fileno(), 4096):
                break
        print(json.dumps({**vars(server.counters), "realtime": rt}), flush=True)


def machine_info() -> dict:
    cpu = platform.processor() or "?"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    from google.protobuf.internal import api_implementation

    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "load_1min": round(os.getloadavg()[0], 2),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "protobuf": api_implementation.Type(),
    }


def measure(target: tuple[str, int], n: int, rate: float, warmup: int, spin: float) -> dict:
    """Run ``warmup`` uncounted exchanges, then ``n`` counted ones, on one simulated controller.

    The garbage collector of this (measuring) process is off while it measures: its history
    lists grow to 10^5 entries and a full collection would be charged to the server.
    """
    sim = SimController()
    if warmup:
        ControllerRunner(sim, target, rate_hz=rate, n=warmup, spin=spin).run()
    runner = ControllerRunner(sim, target, rate_hz=rate, n=n, spin=spin)
    gc.collect()
    gc.disable()
    try:
        t0 = time.perf_counter()
        runner.run()
        wall = time.perf_counter() - t0
    finally:
        gc.enable()
        runner.join()
    st = runner.stats
    rtt_ms = np.array(st.rtt_s) * 1e3 if st.rtt_s else np.array([np.nan])
    p50, p90, p99, p999 = np.percentile(rtt_ms, [50, 90, 99, 99.9])
    return {
        "exchanges": st.sent,
        "replies": st.replies,
        "missed": st.missed,
        "late": st.late,
        "malformed": st.malformed,
        "p50_ms": round(float(p50), 4),
        "p90_ms": round(float(p90), 4),
        "p99_ms": round(float(p99), 4),
        "p999_ms": round(float(p999), 4),
        "max_ms": round(float(np.max(rtt_ms)), 4),
        "rate_hz": rate,
        "wall_s": round(wall, 2),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100_000, help="exchanges (default 10^5)")
    ap.add_argument("--rate", type=float, default=250.0, help="Hz; 0 = flat out (default 250)")
    ap.add_argument("--warmup", type=int, default=250, help="uncounted exchanges first (250)")
    ap.add_argument(
        "--spin-ms",
        type=float,
        default=0.0,
        help="controller busy-waits this long per reply (default 0; needs a spare core)",
    )
    ap.add_argument("--target", help="HOST:PORT of a running EGM sensor (default: start one)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="SCHED_FIFO for both sides (needs CAP_SYS_NICE and --rate > 0)",
    )
    ap.add_argument("--serve", metavar="HOST:PORT", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    try:
        if args.serve:
            serve(args.serve, args.realtime)
            return 0
        if args.n < 1 or args.rate < 0 or args.warmup < 0:
            raise ThinkfastError("--n must be >= 1, --rate >= 0 and --warmup >= 0")
        if args.realtime and args.rate <= 0:
            raise ThinkfastError(
                "--realtime needs --rate > 0 (flat out it would starve the machine)"
            )
        child = None
        if args.target:
            target = parse_hostport(args.target, "--target")
        else:
            child = subprocess.Popen(
                [sys.executable, os.path.abspath(__file__), "--serve", "127.0.0.1:0"]
                + ["--realtime"] * args.realtime,
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            )  # fmt: skip
            target = ("127.0.0.1", int(child.stdout.readline().split()[1]))
        result = {"target": f"{target[0]}:{target[1]}"}
        result["realtime"] = set_realtime() if args.realtime else False
        result.update(measure(target, args.n, args.rate, args.warmup, args.spin_ms / 1e3))
        if child is not None:
            child.stdin.close()
            result["server"] = json.loads(child.stdout.readline())
            child.wait(5)
        result["machine"] = machine_info()
    except (ThinkfastError, OSError, IndexError, ValueError) as exc:
        print(f"egm_latency: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"EGM exchange latency, {args.n} exchanges at {args.rate:g} Hz -> {result['target']}")
    for key in ("realtime", "replies", "missed", "late", "malformed", "p50_ms", "p90_ms", "p99_ms",
                "p999_ms", "max_ms", "wall_s"):  # fmt: skip
        print(f"  {key:<10} {result[key]}")
    for key, value in result["machine"].items():
        print(f"  {key:<10} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
