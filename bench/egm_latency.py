"""EGM exchange latency on loopback: simulated controller (measuring side) <-> EGM sensor.

The measuring side is the simulated ABB controller of ``thinkfast.sim.controller``: each cycle
it sends an ``EgmRobot`` and times the ``EgmSensor`` reply (round trip on ``perf_counter``,
client send -> client receive). A cycle with no reply before the next one is ``missed``; a
reply that comes after its cycle is ``late``; ``in_time_unread`` counts the missed cycles whose
reply had reached the controller's socket in time (kernel arrival stamp) but was read late
because the measuring process itself was stalled.

The server side runs in a separate process: by default this script starts itself with
``--serve`` (an ``EgmServer`` in a dedicated loop whose setpoints go through the safety
supervisor, as in the daemon); ``--target HOST:PORT`` measures any running sensor instead.
``--daemon`` starts the real ``thinkfast-run`` (``--tree``, ``--planner``; EGM on a free
loopback port, zenoh listening on a free loopback TCP port) and, while it measures, keeps it
busy with a throw every ``--throw-period`` seconds (``bench/throw_stream.py`` in a third
process: sampled throws seen by the ZED model, published in real time), so the daemon tracks,
plans, blocks and returns home throughout; the result adds what was thrown and the daemon's own
reply timing (``daemon.egm_timing``: socket wait and reply work, from its last status).

Rates: ``--rate 250`` (default) is the controller's real 4 ms cycle, so the default 10^5
exchanges take 400 s; ``--rate 0`` runs flat out (next request as soon as a reply is in, or
after a 4 ms time-out), which measures the same round trip in a fraction of the time but keeps
the server busier than a real controller would.

The measuring side is a *hot* client by default: it wakes ``--lead-ms`` (1) before each send
and busy-waits to it, then busy-waits up to ``--spin-ms`` (1) for the reply. A real controller
is not a Python process waking from a sleep; on a virtual machine that wake-up costs several
times the work, and it would be charged to the sensor. ``--lead-ms 0 --spin-ms 0`` is the cold
client of the earlier figures.

The daemon runs with its deployment settings (``thinkfast-run --spin-ahead-ms 1 --cpu 1``:
spin on the EGM socket from 1 ms before each packet is due, EGM loop on CPU 1, zenoh's threads
and this controller on the others); ``--busy-poll`` spins all the time instead, ``--cpu -1``
does not pin. ``--realtime`` puts this controller and the daemon's EGM thread (``--fifo 50``)
under SCHED_FIFO (CAP_SYS_NICE). The ``--serve`` loop honours ``--busy-poll`` and ``--cpu``
(it has no executor, so nothing to prepare ahead).

The first ``--warmup`` exchanges (default 250) are not counted. Round trips include any
scheduling delay of either process, so a loaded machine shows in the tail (``load_1min``). The
``wire_*`` figures time the same round trips to the reply's kernel arrival stamp on this side's
socket (Linux, ``SO_TIMESTAMPNS``) instead of the moment this process read it: the sensor's share
without this measuring process's own wake-up and preemption (on two cores it shares a CPU with
the daemon's planner and zenoh), what a controller on its own real-time hardware would see.

    python bench/egm_latency.py --n 20000 --rate 0 --json
    python bench/egm_latency.py --daemon --realtime --json   # 10^5 exchanges: ~7 min
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import select
import shlex
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from thinkfast.control.safety import SafetyConfig, SafetySupervisor
from thinkfast.control.safety_limits import make_limits
from thinkfast.errors import ThinkfastError
from thinkfast.link.egm_server import EgmServer, parse_hostport
from thinkfast.link.rt_thread import pin_thread
from thinkfast.sim.child_log import log_text
from thinkfast.sim.controller import SimController, servo_for
from thinkfast.sim.controller_runner import ControllerRunner

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"


def set_realtime(priority: int = 50) -> bool:
    """Put the calling thread under SCHED_FIFO (needs CAP_SYS_NICE); False if refused."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError):
        return False
    return True


def serve(bind: str, realtime: bool, busy: bool, cpu: int) -> None:
    """Server side: reply to every EgmRobot until stdin closes, then print counters as JSON.
    ``busy``: spin on the socket instead of sleeping in ``select`` (as ``thinkfast-run
    --busy-poll``); ``cpu`` >= 0: run on that CPU."""
    from thinkfast.robot.model import load_robot

    servo = servo_for(load_robot())  # no tree here: the default robot's limits
    cfg = SafetyConfig()
    limits = make_limits(
        servo.q_min, servo.q_max, servo.v_max, servo.a_max, [10 * a for a in servo.a_max],
        cfg.position_margin,
    )  # fmt: skip
    state: dict = {}

    def reply(fb, before=None):
        sup = state.get("sup")
        if sup is None:
            sup = state["sup"] = SafetySupervisor(limits, cfg, fb.q_rad)
            state["q0"], state["k"] = fb.q_rad.copy(), 0
        state["k"] += 1
        t = state["k"] * cfg.dt  # a slow sine on every joint: the supervisor passes it through
        q = state["q0"] + 0.2 * (1.0 - np.cos(2.0 * t))  # starts at rest
        cmd = sup.step(q, 0.4 * np.sin(2.0 * t) * np.ones(6), q_meas=fb.q_rad)
        return cmd.q, cmd.qd

    if cpu >= 0:
        pin_thread(cpu)
    with EgmServer(bind, reply) as server:
        rt = set_realtime() if realtime else False
        gc.freeze()  # set-up objects out of the collector's way, as a daemon would
        print(f"PORT {server.address[1]} {int(rt)}", flush=True)
        fds = [server.fileno(), sys.stdin.fileno()]
        wait = 0.0 if busy else 1.0  # busy: never sleep, spin on both descriptors
        while True:
            ready, _, _ = select.select(fds, [], [], wait)
            if server.fileno() in ready:
                server.poll()
            if sys.stdin.fileno() in ready and not os.read(sys.stdin.fileno(), 4096):
                break
        print(json.dumps({**vars(server.counters), "realtime": rt, "busy_poll": busy}), flush=True)


def _off_cpu(cpu: int):
    """A ``preexec_fn`` that keeps a child (the camera's stand-in) and its threads off the
    sensor's CPU ``cpu``, as a cell's detector service is kept off it (docs/DEPLOY.md); None
    when nothing is pinned."""
    others = os.sched_getaffinity(0) - {cpu}
    if cpu < 0 or not others:
        return None
    return lambda: os.sched_setaffinity(0, others)


def _pin_client(cpu: int) -> None:
    """Keep this (measuring) process off the sensor's CPU ``cpu`` (when >= 0)."""
    others = os.sched_getaffinity(0) - {cpu}
    if cpu >= 0 and others:
        os.sched_setaffinity(0, others)


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


def measure(
    target: tuple[str, int],
    n: int,
    rate: float,
    warmup: int,
    spin: float,
    lead: float = 0.0,
    q0=None,
    on_start=None,
) -> dict:
    """Run ``warmup`` uncounted exchanges, then ``n`` counted ones, on one simulated controller.

    The garbage collector of this (measuring) process is off while it measures: its history
    lists grow to 10^5 entries and a full collection would be charged to the server.

    Args:
        spin, lead: the controller's busy-waits [s] for a reply and before a send (see
            :class:`ControllerRunner`).
        q0: the simulated arm's starting joints [rad] (6,); zeros by default.
        on_start: called between the warm-up and the counted exchanges.
    """
    sim = SimController(q0=q0)
    bind = ("127.0.0.1", 0)
    if warmup:
        warm = ControllerRunner(sim, target, rate_hz=rate, n=warmup, spin=spin, lead=lead)
        warm.run()
        bind = warm.address  # a controller sends from one port: the sensor keeps its peer
        warm.join()
    if on_start is not None:
        on_start()
    runner = ControllerRunner(sim, target, rate_hz=rate, n=n, spin=spin, lead=lead, bind=bind)
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
    wire_ms = np.array(st.wire_s) * 1e3 if st.wire_s else np.array([np.nan])
    w50, w99, w999 = np.percentile(wire_ms, [50, 99, 99.9])
    return {
        "exchanges": st.sent,
        "replies": st.replies,
        "missed": st.missed,
        "late": st.late,
        "in_time_unread": st.in_time_unread,
        "malformed": st.malformed,
        "p50_ms": round(float(p50), 4),
        "p90_ms": round(float(p90), 4),
        "p99_ms": round(float(p99), 4),
        "p999_ms": round(float(p999), 4),
        "max_ms": round(float(np.max(rtt_ms)), 4),
        "wire_p50_ms": round(float(w50), 4),
        "wire_p99_ms": round(float(w99), 4),
        "wire_p999_ms": round(float(w999), 4),
        "wire_max_ms": round(float(np.max(wire_ms)), 4),
        "rate_hz": rate,
        "wall_s": round(wall, 2),
    }


def run_daemon(args) -> dict:
    """``--daemon``: the real ``thinkfast-run`` with a stream of throws (see the module doc)."""
    from thinkfast.contract.zenoh_session import loopback_endpoint
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.robot_match import robot_for_tree

    tree = Path(args.tree)
    if not tree.is_file():
        raise ThinkfastError(f"{tree}: no tree file; build it with `make demo`")
    home = robot_for_tree(load_tree(tree).meta, str(tree)).home  # the simulated arm starts there
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        egm_port = s.getsockname()[1]
    zenoh_ep, prefix = loopback_endpoint(), f"egmbench{os.getpid()}"
    config = ["--config", args.config] if args.config else []
    exe = args.daemon_exe or str(Path(sys.executable).parent / "thinkfast-run")
    record = ["--record", args.record] if args.record else []
    cmd = [exe, "--tree", str(tree), "--planner", args.planner, "--egm-bind",
           f"127.0.0.1:{egm_port}", "--zenoh-listen", zenoh_ep, "--key-prefix", prefix,
           "--log-level", "warning", *config, *record]  # fmt: skip
    if args.busy_poll or args.spin_ahead_ms > 0:
        cmd += ["--busy-poll"] if args.busy_poll else ["--spin-ahead-ms", str(args.spin_ahead_ms)]
    cmd += ["--cpu", str(args.cpu)] if args.cpu >= 0 else []
    cmd += ["--fifo", "50"] if args.realtime else []  # the EGM thread only, not zenoh's
    cmd += shlex.split(args.daemon_args)  # e.g. "--rerun save=/tmp/x.rrd"
    n_throws = int((args.n + args.warmup) / args.rate / args.throw_period) + 3
    stream_cmd = [sys.executable, str(Path(__file__).with_name("throw_stream.py")), "--connect",
                  zenoh_ep, "--prefix", prefix, "--period", str(args.throw_period), "--throws",
                  str(n_throws), "--seed", str(args.seed), "--wait-go", *config]  # fmt: skip
    log = tempfile.TemporaryFile("w+")
    daemon = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log)
    stream = subprocess.Popen(stream_cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True, preexec_fn=_off_cpu(args.cpu))  # fmt: skip
    result = {"target": f"127.0.0.1:{egm_port}", "mode": "daemon", "planner": args.planner,
              "tree": str(tree), "throw_period_s": args.throw_period,
              "daemon_options": cmd[cmd.index("--log-level") + 2:]}  # fmt: skip
    try:
        if stream.stdout.readline().strip() != "READY":
            raise ThinkfastError(f"the daemon did not come up: {_tail(log, daemon)}")
        _pin_client(args.cpu)
        rt = set_realtime() if args.realtime else False

        def start_throws() -> None:
            stream.stdin.write("go\n")
            stream.stdin.flush()

        result["realtime"] = rt
        result["load_avg_start"] = [round(x, 2) for x in os.getloadavg()]
        result.update(measure(("127.0.0.1", egm_port), args.n, args.rate, args.warmup,
                              args.spin_ms / 1e3, args.lead_ms / 1e3, q0=home,
                              on_start=start_throws))  # fmt: skip
        stream.stdin.close()
        published = json.loads(stream.stdout.readline() or "{}")
        status = published.pop("status", None) or {}
        result.update(published)
        result["daemon"] = {k: status.get(k) for k in _DAEMON_KEYS}
    finally:
        _stop(stream, 10.0)
        result.setdefault("daemon", {})["exit_code"] = _stop(daemon, 20.0)
    if result["daemon"]["exit_code"] != 0:
        result["daemon"]["log"] = _tail(log, daemon)
    return result


_DAEMON_KEYS = ("throws", "state", "egm", "egm_timing", "detections", "safety", "planner_errors")


def _stop(proc: subprocess.Popen, timeout: float) -> int | None:
    """Stop a child: close its stdin if piped (the stream), else SIGINT (the daemon brakes and
    exits 0); kill it after ``timeout`` [s]. Returns the exit code (None when killed)."""
    if proc.stdin is not None:
        if not proc.stdin.closed:
            proc.stdin.close()
    elif proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return None


def _tail(log, proc, n: int = 2000) -> str:
    return f"exit code {proc.poll()}: {log_text(log)[-n:].strip()}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100_000, help="exchanges (default 10^5)")
    ap.add_argument("--rate", type=float, default=250.0, help="Hz; 0 = flat out (default 250)")
    ap.add_argument("--warmup", type=int, default=250, help="uncounted exchanges first (250)")
    ap.add_argument(
        "--spin-ms",
        type=float,
        default=1.0,
        help="controller busy-waits up to this long for each reply before blocking "
        "(default 1; 0 blocks at once)",
    )
    ap.add_argument(
        "--lead-ms",
        type=float,
        default=1.0,
        help="controller wakes this long before each send and busy-waits to it (default 1; "
        "0 sleeps to the send: with --spin-ms 0, the cold client of earlier figures)",
    )
    ap.add_argument(
        "--busy-poll",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="the sensor never sleeps: thinkfast-run --busy-poll, or the --serve loop",
    )
    ap.add_argument(
        "--spin-ahead-ms",
        type=float,
        default=1.0,
        help="--daemon: thinkfast-run --spin-ahead-ms (default 1)",
    )
    ap.add_argument(
        "--cpu",
        type=int,
        default=1,
        help="the sensor's CPU (thinkfast-run --cpu, or the --serve loop's), this controller "
        "on the others (default 1; -1: no pinning)",
    )
    ap.add_argument("--target", help="HOST:PORT of a running EGM sensor (default: start one)")
    ap.add_argument("--daemon", action="store_true", help="measure thinkfast-run under throws")
    ap.add_argument("--tree", default=str(DEFAULT_TREE), help="--daemon: tree file (default)")
    ap.add_argument("--planner", default="tree", choices=("tree", "naive"), help="--daemon")
    ap.add_argument("--config", help="--daemon: runtime TOML for the daemon and the camera")
    ap.add_argument("--throw-period", type=float, default=3.5, help="--daemon: s per throw")
    ap.add_argument("--seed", type=int, default=0, help="--daemon: throws and camera noise")
    ap.add_argument("--record", help="--daemon: the daemon's flight record (HDF5)")
    ap.add_argument("--daemon-exe", help="--daemon: daemon executable (default thinkfast-run)")
    ap.add_argument(
        "--daemon-args",
        default="",
        help='--daemon: more thinkfast-run options, one string (e.g. "--rerun save=/tmp/x.rrd")',
    )
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="SCHED_FIFO for both sides: this controller and the daemon's EGM thread "
        "(--fifo 50) or the --serve loop (needs CAP_SYS_NICE, --rate > 0, no --busy-poll)",
    )
    ap.add_argument("--serve", metavar="HOST:PORT", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    try:
        if args.serve:
            serve(args.serve, args.realtime, args.busy_poll, args.cpu)
            return 0
        if args.n < 1 or args.rate < 0 or args.warmup < 0 or min(args.spin_ms, args.lead_ms) < 0:
            raise ThinkfastError("--n must be >= 1, --rate, --warmup, --spin-ms and --lead-ms >= 0")
        if args.realtime and args.busy_poll and not args.target:
            raise ThinkfastError(
                "--realtime needs --no-busy-poll (a spinning SCHED_FIFO thread starves its core "
                "and the kernel throttles it: sched_rt_runtime_us)"
            )
        if args.realtime and args.rate <= 0:
            raise ThinkfastError(
                "--realtime needs --rate > 0 (flat out it would starve the machine)"
            )
        if args.daemon and args.target:
            raise ThinkfastError("--daemon and --target exclude each other")
        if args.daemon and args.rate <= 0:
            raise ThinkfastError("--daemon needs --rate > 0 (the daemon expects a 4 ms cycle)")
        child = None
        if args.daemon:
            target = None
            result = run_daemon(args)
        elif args.target:
            target = parse_hostport(args.target, "--target")
        else:
            child = subprocess.Popen(
                [sys.executable, os.path.abspath(__file__), "--serve", "127.0.0.1:0"]
                + ["--realtime"] * args.realtime + ["--busy-poll"] * args.busy_poll
                + ["--cpu", str(args.cpu)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            )  # fmt: skip
            target = ("127.0.0.1", int(child.stdout.readline().split()[1]))
            _pin_client(args.cpu)
        if target is not None:
            result = {"target": f"{target[0]}:{target[1]}"}
            result["realtime"] = set_realtime() if args.realtime else False
            result.update(
                measure(target, args.n, args.rate, args.warmup, args.spin_ms / 1e3,
                        args.lead_ms / 1e3)
            )  # fmt: skip
        if child is not None:
            child.stdin.close()
            result["server"] = json.loads(child.stdout.readline())
            child.wait(5)
        result["machine"] = machine_info()
        result["machine"]["load_avg"] = [round(x, 2) for x in os.getloadavg()]
    except (ThinkfastError, OSError, IndexError, ValueError) as exc:
        print(f"egm_latency: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"EGM exchange latency, {args.n} exchanges at {args.rate:g} Hz -> {result['target']}")
    for key in ("realtime", "replies", "missed", "late", "in_time_unread", "malformed", "p50_ms",
                "p90_ms", "p99_ms", "p999_ms", "max_ms", "wire_p50_ms", "wire_p99_ms",
                "wire_p999_ms", "wire_max_ms", "wall_s", "throws_published"):  # fmt: skip
        if key in result:
            print(f"  {key:<10} {result[key]}")
    daemon = result.get("daemon") or {}
    for key in ("exit_code", "throws", "egm_timing", "safety", "planner_errors"):
        if key in daemon:
            print(f"  daemon {key:<14} {daemon[key]}")
    for key, value in result["machine"].items():
        print(f"  {key:<10} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
