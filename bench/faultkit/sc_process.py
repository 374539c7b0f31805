"""Scenarios of the daemon's process and its edges: fuzzed detections, SIGINT/SIGTERM mid-throw,
the zenoh peer lost and back, and recording to a full, read-only or missing target."""

from __future__ import annotations

import signal
import subprocess
import threading
import time

import numpy as np

from bench.faultkit import rows as R
from bench.faultkit import spawn
from bench.faultkit.cell import Cell
from bench.faultkit.scenario import (
    blocked_summary,
    easy_throw,
    error_result,
    far_throw,
    finish,
    sampled_throws,
    scenario,
    when_moving,
)


def start_fuzz(cell: Cell, n: int, seconds: float, seed: int) -> subprocess.Popen:
    """The fuzz stream (:mod:`bench.faultkit.fuzz`) in a process of its own."""
    args = ("--connect", cell.endpoint, "--prefix", cell.prefix, "--n", str(n),
            "--seconds", str(seconds), "--seed", str(seed))  # fmt: skip
    return spawn("fuzz", *args, stdout=subprocess.PIPE, text=True)


def fuzz_result(proc: subprocess.Popen, timeout: float) -> dict:
    import json

    try:
        out, _ = proc.communicate(timeout=timeout)
        return json.loads(out.strip().splitlines()[-1])
    except (subprocess.TimeoutExpired, ValueError, IndexError):
        proc.kill()
        proc.communicate()
        return {"error": "the fuzz stream did not finish"}


def detection_counts(status: dict) -> dict:
    """accepted / rejected / dropped totals of a status (empty when it has none)."""
    d = status.get("detections")
    if not isinstance(d, dict):
        return {}
    rej, drop = d.get("rejected") or {}, d.get("dropped") or {}
    return {"accepted": d.get("accepted", 0), "rejected": sum(rej.values()),
            "dropped": sum(drop.values())}  # fmt: skip


@scenario("fuzz_detections", ">= 10^4 hostile payloads of 65 kinds in kHz bursts during throws")
def fuzz_detections(ctx, opts):
    t_start = time.time()
    n, seconds = (2000, 8.0) if opts.quick else (10_000, 24.0)
    cell = Cell(ctx, seed=ctx.seed)
    try:
        cell.start()
        proc = start_fuzz(cell, n, seconds, ctx.seed)
        outs = []
        for i, th in enumerate(sampled_throws(ctx, 100)):
            if proc.poll() is not None or time.time() - t_start > seconds + 30:
                break
            outs.append(cell.throw(th, i))
        fz = fuzz_result(proc, seconds + 60)
        time.sleep(2.0)  # the daemon drains its queue
        counts = detection_counts(cell.status())
        fig = {**blocked_summary(outs), "fuzz_sent": fz.get("sent"), "kinds": fz.get("kinds"),
               "max_burst_hz": fz.get("max_burst_hz"), "real_published": cell.published,
               **counts}  # fmt: skip
        fails = [] if fz.get("sent") else [f"fuzz stream: {fz}"]
        if counts:
            accepted_fuzz = counts["accepted"] - cell.published
            fig["uncounted"] = cell.published + (fz.get("sent") or 0) - sum(counts.values())
            if accepted_fuzz > 0:
                fails.append(f"{accepted_fuzz} fuzzed payloads accepted")
        if outs and not any(o.executed for o in outs):
            fails.append("no throw executed during the fuzz")
        return finish("fuzz_detections", cell, t_start, fig, fails, opts=opts)
    except Exception as exc:
        cell.close()
        return error_result("fuzz_detections", t_start, exc)


def _signal(name: str, sig: int, ctx, opts):
    """Signal the daemon 0.15 s after the arm starts moving towards a far goal (naive planner:
    it moves at once); it must brake smoothly (the checker's jerk checks), stop, exit 0."""
    t_start = time.time()
    cell = Cell(ctx, planner="naive", seed=ctx.seed)
    sent: list[float] = []
    figures: dict = {}

    def fire():
        sent.append(time.time())
        cell.send_signal(sig)

    def after(fig):  # the cycles from the signal to the exit
        fails = [] if sent else ["the arm never moved: no signal sent"]
        rows = cell.rows_between(sent[0] if sent else 0.0, np.inf)
        rows = rows[rows[:, R.N_VALID] > 0]
        if len(rows) and np.abs(rows[-1, R.CMD_QD]).max() > 0:
            fails.append("still moving when it exited")
        if not fig.get("brake_cycles"):
            fails.append("no brake seen")
        speed = float(np.abs(rows[0, R.CMD_QD]).max()) if len(rows) else 0.0
        figures.update({"speed_at_signal": round(speed, 3), "brake_s": round(len(rows) * 0.004, 3)})
        return fails

    try:
        cell.start()
        cell.throw(far_throw(1), 0, [(0.0, when_moving(cell, fire, delay=0.15))], settle=0.0)
        try:
            cell.proc.wait(15.0)
        except subprocess.TimeoutExpired:
            pass
        return finish(name, cell, t_start, figures, [], sig=sig, extra=after, opts=opts)
    except Exception as exc:
        cell.close()
        return error_result(name, t_start, exc)


scenario("sigint", "SIGINT while the arm moves fast: smooth brake, exit 0")(
    lambda ctx, opts: _signal("sigint", signal.SIGINT, ctx, opts)
)
scenario("sigterm", "SIGTERM while the arm moves fast: smooth brake, exit 0")(
    lambda ctx, opts: _signal("sigterm", signal.SIGTERM, ctx, opts)
)


@scenario("zenoh_peer_lost", "the detection publisher's session closes mid-throw, reopens 2 s on")
def zenoh_peer_lost(ctx, opts):
    t_start = time.time()
    cell = Cell(ctx, seed=ctx.seed)
    try:
        cell.start()
        first = cell.throw(easy_throw(0), 0)
        stop = threading.Event()

        def drop():
            stop.set()
            time.sleep(0.05)
            cell.close_publisher()

        t_lost = time.time()
        cell.throw(easy_throw(1), 1, [(0.15, drop)], stop=stop)
        time.sleep(2.0)
        during = cell.rows_between(t_lost, time.time())
        cell.open_publisher()
        nxt = cell.throw(easy_throw(2), 2)
        fig = {"first_blocked": first.result.blocked, "next_executed": nxt.executed,
               "next_blocked": nxt.result.blocked,
               "answered_while_lost_pct": round(100.0 * float(np.mean(during[:, R.N_VALID] > 0)), 2)
               if len(during) else None}  # fmt: skip
        fails = [] if nxt.executed and nxt.result.blocked else ["the next throw was not blocked"]
        return finish("zenoh_peer_lost", cell, t_start, fig, fails, opts=opts)
    except Exception as exc:
        cell.close()
        return error_result("zenoh_peer_lost", t_start, exc)
