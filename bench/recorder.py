"""Flight recorder under a daemon's load: the cost of each row method and the memory it takes.

A real-time loop like the daemon's EGM thread: one ``egm`` row every 4 ms (250 Hz); a throw
every 3.5 s brings 1 s of detections at 50 Hz (``raw``, ``detection``, ``belief``,
``decision`` each) that start with a burst of 25 at once (a drained zenoh queue), and two
``event`` rows. Each call is timed (perf_counter_ns). ``wake`` is an empty call made first after
each sleep: on a virtual machine the first calls after a sleep run several times slower.
``(shipping)`` are the calls that sent batches to the writer (one system call). ``--service``
calls ``Recorder.service()`` after every egm row, as a daemon would in idle time (the row
methods then never ship). ``--spin`` spins to the next tick instead of sleeping (as the daemon
with ``--spin-ahead-ms`` or ``--busy-poll``). ``--stall S`` stops the writer (SIGSTOP) for S
seconds midway: rows are dropped and counted, memory stays flat (``--egm-per-tick 10``: ten
egm rows every 4 ms, to fill the pipe sooner). Memory: resident set of this
process (the daemon's side) after 1 s and at the end (it includes this bench's own timing
buffers, 8 bytes a call, shown), and the writer's peak. ``warm`` is the
median cost of each method called back to back 1000 times (hot caches).

``--v1`` runs the schema-1 recorder (bench/recorder_v1.py: rows kept in memory, the file
written at close) instead, to compare.

    python bench/recorder.py [--seconds 10] [--service] [--spin] [--stall 3] [--egm-per-tick 1]
                             [--v1] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from array import array
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from thinkfast.record.format import read_record
from thinkfast.record.recorder import Recorder

sys.path.insert(0, str(Path(__file__).parent))
from recorder_v1 import V1Recorder  # noqa: E402 - the schema-1 recorder, for --v1

DT, THROW_PERIOD, FLIGHT, DET_DT, BURST = 0.004, 3.5, 1.0, 0.02, 25


def rss_kb(pid: int | str = "self", key: str = "VmRSS") -> int:
    """A memory figure of a process from /proc [kB] (0 if gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def run(
    seconds: float,
    service: bool,
    stall: float,
    spin: bool,
    path: Path,
    per_tick: int = 1,
    v1: bool = False,
) -> dict:
    rng = np.random.default_rng(1)
    rec = (V1Recorder if v1 else Recorder)(path, {"planner": "tree", "bench": True})
    writer = rec.writer_pid
    names = ("wake", "egm", "raw", "detection", "belief", "decision", "event", "service")
    cost = {k: array("q") for k in (*names, "(shipping)")}  # ns; 8 bytes a call
    belief = SimpleNamespace(t=0.0, mean=rng.normal(size=6), cov=np.eye(6) * 1e-3)
    crossing = SimpleNamespace(ok=True, mean=rng.normal(size=3), cov=np.eye(3) * 1e-4)
    q = rng.normal(size=(3, 6))
    payload = json.dumps({"stamp": 0.0, "position": [7.1, 0.2, 1.4], "seq": 1}).encode()
    clock = time.perf_counter_ns

    def timed(name, fn, *args):
        shipped = rec.shipped
        t0 = clock()
        fn(*args)
        dt = clock() - t0
        cost[name].append(dt)
        if rec.shipped != shipped:  # this call sent batches to the writer
            cost["(shipping)"].append(dt)

    def detections(now: float, n: int) -> None:
        for _ in range(n):
            timed("raw", rec.raw, now, payload)
            timed("detection", rec.detection, now, now - 0.04, q[0, :3], 7)
            timed("belief", rec.belief, now, belief, crossing)
            timed("decision", rec.decision, now, "tracking", 3, 0.8, 5)

    start = time.monotonic()
    rss_1s = 0
    stop_at, resume_at = start + (seconds - stall) / 2, start + (seconds + stall) / 2
    stopped = False
    tick, seqno, next_det = start, 0, start
    while (now := time.monotonic()) < start + seconds:
        if stall and writer and not stopped and stop_at <= now < resume_at:
            os.kill(writer, signal.SIGSTOP)
            stopped = True
        elif stopped and now >= resume_at:
            os.kill(writer, signal.SIGCONT)
            stopped = False
        t = time.time()
        timed("wake", _noop, t, seqno, q[0], q[1], q[2], False)  # first call after a sleep
        for _ in range(per_tick):
            timed("egm", rec.egm, t, seqno, q[0], q[1], q[2], False)
            seqno += 1
        if service:
            timed("service", rec.service)
        phase = (now - start) % THROW_PERIOD
        if phase < FLIGHT and now >= next_det:
            if phase < DT:
                timed("event", rec.event, t, "throw_start", {"planner": "tree", "node": 0})
                detections(t, BURST)
            else:
                detections(t, 1)
            next_det = now + DET_DT
        if FLIGHT <= phase < FLIGHT + DT:
            timed("event", rec.event, t, "throw_end", {"brakes": 0, "interventions": {}})
        if not rss_1s and now - start >= 1.0:
            rss_1s = rss_kb()
        tick += DT
        if spin:
            while time.monotonic() < tick:
                pass
        else:
            time.sleep(max(0.0, tick - time.monotonic()))
    rss_end, writer_peak = rss_kb(), rss_kb(writer, "VmHWM") if writer else 0
    status = rec.status()
    t0 = time.monotonic()
    rec.close()
    close_s = time.monotonic() - t0
    final = rec.status()
    r = read_record(path)
    in_file = sum(len(v) for v in r.tables.values()) + len(r.raw_payloads) + len(r.events)
    return {
        "seconds": seconds,
        "service": service,
        "stall_s": stall,
        "spin": spin,
        "egm_per_tick": per_tick,
        "v1": v1,
        "cost_us": {k: _summary(v) for k, v in cost.items() if v},
        "rows": final["rows"],
        "dropped": final["dropped"],
        "rows_in_file": in_file,
        "state": final["state"],
        "status_before_close": status,
        "close_s": round(close_s, 4),
        "file_mb": round(path.stat().st_size / 1e6, 3),
        "rss_mb_after_1s": round(rss_1s / 1024, 1),
        "rss_mb_end": round(rss_end / 1024, 1),
        "timing_buffers_mb": round(sum(8 * len(v) for v in cost.values()) / 1e6, 2),
        "writer_peak_rss_mb": round(writer_peak / 1024, 1),
        "in_flight_bound_mb": round(rec.in_flight_bytes / 1e6, 2),
    }


def warm_costs(path: Path, n: int = 1000, cls=Recorder) -> dict:
    """Median cost [us] of each row method called ``n`` times back to back (service() every
    25 calls, not timed; few enough rows that nothing is dropped)."""
    rng = np.random.default_rng(2)
    rec = cls(path, {})
    q = rng.normal(size=(3, 6))
    b = SimpleNamespace(t=0.0, mean=q[0], cov=np.eye(6))
    c = SimpleNamespace(ok=True, mean=q[1, :3], cov=np.eye(3))
    calls = {
        "egm": lambda i: rec.egm(1.0, i, q[0], q[1], q[2], False),
        "raw": lambda i: rec.raw(1.0, b'{"stamp": 0.0, "position": [7.1, 0.2, 1.4], "seq": 1}'),
        "detection": lambda i: rec.detection(1.0, 0.9, q[0, :3], i),
        "belief": lambda i: rec.belief(1.0, b, c),
        "decision": lambda i: rec.decision(1.0, "tracking", 3, 0.8, 5),
        "event": lambda i: rec.event(1.0, "brake", {"reason": "deviation", "joint": 2}),
    }
    out = {}
    clock = time.perf_counter_ns
    for name, fn in calls.items():
        ns = []
        for i in range(n):
            t0 = clock()
            fn(i)
            ns.append(clock() - t0)
            if i % 25 == 0:
                rec.service()
                rec._service_at = 0.0  # ship at every call of service(), not every 0.1 s
        out[name] = round(float(np.median(ns)) / 1e3, 2)
        time.sleep(0.2)  # let the writer drain the pipe
    dropped = rec.status()["dropped"]
    rec.close()
    out["dropped"] = dropped
    return out


def _noop(*_args) -> None:
    """A call that does nothing: what any call costs right after a sleep on this machine."""


def _summary(ns) -> dict:
    a = np.asarray(ns) / 1e3
    return {
        "calls": len(a),
        "p50": round(float(np.percentile(a, 50)), 2),
        "p99": round(float(np.percentile(a, 99)), 2),
        "max": round(float(a.max()), 1),
        "mean": round(float(a.mean()), 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--service", action="store_true", help="call service() after every egm row")
    ap.add_argument("--stall", type=float, default=0.0, help="stop the writer for S s midway")
    ap.add_argument("--spin", action="store_true", help="spin between ticks instead of sleeping")
    ap.add_argument("--egm-per-tick", type=int, default=1, help="egm rows every 4 ms (load)")
    ap.add_argument("--v1", action="store_true", help="the schema-1 recorder instead (compare)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        res = run(
            args.seconds, args.service, args.stall, args.spin, Path(d) / "bench.h5",
            args.egm_per_tick, args.v1,
        )  # fmt: skip
        res["warm_median_us"] = warm_costs(
            Path(d) / "warm.h5", cls=V1Recorder if args.v1 else Recorder
        )
    if args.json:
        print(json.dumps(res))
        return
    print(
        f"recorder, {args.seconds:g} s real time, service={args.service}, "
        f"stall={args.stall:g} s, spin={args.spin}, egm rows per tick={args.egm_per_tick}"
        + (", SCHEMA-1 RECORDER" if args.v1 else "")
    )
    print(f"{'method':<10} {'calls':>7} {'p50 us':>8} {'p99 us':>8} {'max us':>8} {'mean us':>8}")
    for k, s in res["cost_us"].items():
        print(f"{k:<10} {s['calls']:>7} {s['p50']:>8} {s['p99']:>8} {s['max']:>8} {s['mean']:>8}")
    print("warm (back to back, median us):", res["warm_median_us"])
    keys = "rows dropped rows_in_file state close_s file_mb rss_mb_after_1s rss_mb_end"
    keys += " timing_buffers_mb writer_peak_rss_mb in_flight_bound_mb"
    for k in keys.split():
        print(f"{k:<20} {res[k]}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
