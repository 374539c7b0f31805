"""Scenarios on the EGM wire: malformed datagrams, duplicates, a second sender, a flood, absurd
feedback, seqno resets. Each runs a few throws (one in quick mode) through the faulty wire."""

from __future__ import annotations

import time

import numpy as np

from bench.faultkit import rows as R
from bench.faultkit.cell import Cell
from bench.faultkit.flood import Flood
from bench.faultkit.scenario import (
    blocked_summary,
    easy_throw,
    error_result,
    finish,
    scenario,
    when_moving,
)
from bench.faultkit.senders import SecondSender


def _throws(cell: Cell, opts, hooks=lambda i: ()) -> list:
    n = 1 if opts.quick else 3
    return [cell.throw(easy_throw(i), i, hooks(i)) for i in range(n)]


def _run(name, ctx, opts, body, **finish_kw):
    """Start a cell, run ``body(cell) -> (figures, failures)``, finish; errors become results."""
    t_start = time.time()
    cell = Cell(ctx, seed=ctx.seed)
    try:
        cell.start()
        figures, failures = body(cell)
        return finish(name, cell, t_start, figures, failures, opts=opts, **finish_kw)
    except Exception as exc:
        cell.close()
        return error_result(name, t_start, exc)


@scenario("malformed", "malformed datagrams from the peer's socket (0.5 per cycle) during throws")
def malformed(ctx, opts):
    def body(cell):
        cell.ctl.malformed = 0.5
        outs = _throws(cell, opts)
        cell.ctl.malformed = 0.0
        time.sleep(0.2)
        sent = cell.ctl.malformed_sent
        fig = {**blocked_summary(outs), "malformed_sent": sent,
               "daemon_malformed": cell.monitor.egm().get("malformed")}  # fmt: skip
        fails = [] if all(o.executed for o in outs) else ["a throw was not executed"]
        return fig, fails

    def extra(fig):
        n = fig.get("extra_replies") or 0
        return [f"{n} replies to malformed datagrams"] if n else []

    return _run("malformed", ctx, opts, body, extra=extra)


@scenario("duplicated", "every EgmRobot sent twice during throws")
def duplicated(ctx, opts):
    def body(cell):
        cell.ctl.duplicate = True
        outs = _throws(cell, opts)
        cell.ctl.duplicate = False
        fails = [] if all(o.executed for o in outs) else ["a throw was not executed"]
        return blocked_summary(outs), fails

    return _run("duplicated", ctx, opts, body)


@scenario("second_sender", "another socket sends valid EgmRobot at 250 Hz (another arm's joints)")
def second_sender(ctx, opts):
    def body(cell):
        other = SecondSender(("127.0.0.1", cell.egm_port), ctx.robot.home + 0.3).start()
        try:
            outs = _throws(cell, opts)
        finally:
            counts = other.stop()
        fig = {**blocked_summary(outs), "second_sent": counts["sent"],
               "second_replies": counts["replies"]}  # fmt: skip
        fails = [] if all(o.executed for o in outs) else ["a throw was not executed"]
        if counts["replies"]:
            fails.append(f"the second sender got {counts['replies']} replies")
        return fig, fails

    return _run("second_sender", ctx, opts, body)


@scenario("flood", "10^4 datagrams/s for 3 s from another port (garbage and valid-looking)")
def flood(ctx, opts):
    def body(cell):
        rate, seconds = 10_000, 1.5 if opts.quick else 3.0
        cell.throw(easy_throw(0), 0)
        t0 = time.time()
        fl = Flood(cell.egm_port, rate=rate, seconds=seconds, max_packets=int(rate * seconds),
                   seed=ctx.seed)  # fmt: skip
        out = cell.throw(easy_throw(1), 1)  # the flood runs through this throw
        res = fl.result()
        t1 = t0 + 0.5 + float(res.get("seconds", seconds))  # the flood starts ~0.5 s late
        rows = cell.rows_between(t0 + 0.5, t1)
        fig = {
            "flood": res,
            "executed_in_flood": out.executed,
            "blocked_in_flood": out.result.blocked,
        }
        fig.update(_window(rows))
        fails = []
        if res.get("replies", 0):
            fails.append(f"the flooder got {res['replies']} replies")
        if fig["answered_in_flood_pct"] is not None and fig["answered_in_flood_pct"] < 90.0:
            fails.append(f"answered {fig['answered_in_flood_pct']} % during the flood")
        return fig, fails

    return _run("flood", ctx, opts, body, replies=False)


def _window(rows: np.ndarray) -> dict:
    """Answered share and round trips [ms] of the peer's cycles in ``rows``."""
    if len(rows) == 0:
        return {"answered_in_flood_pct": None}
    ok = rows[:, R.N_VALID] > 0
    rtt = 1e3 * (rows[ok, R.T_ARR] - rows[ok, R.T_SEND])
    p50, p99 = np.percentile(rtt, [50, 99]) if len(rtt) else (np.nan, np.nan)
    rtt_ms = {"p50": round(float(p50), 3), "p99": round(float(p99), 3),
              "max": round(float(rtt.max()), 3) if len(rtt) else None}  # fmt: skip
    return {"answered_in_flood_pct": round(100.0 * ok.mean(), 2), "cycles_in_flood": len(rows),
            "rtt_in_flood_ms": rtt_ms}  # fmt: skip


@scenario("absurd_feedback", "joints jumping by 2.5 rad, beyond the URDF limits, 100 rad (finite)")
def absurd_feedback(ctx, opts):
    """Isolated absurd packets at rest 1.5 s apart (one packet, one beyond the limits, a burst of
    +-3 rad jumps, 100 rad for 5 cycles), then one in motion. One isolated packet must not latch
    a fault (later ones may: repeated faults); commands stay within every limit throughout."""
    home = ctx.robot.home

    def jump(j, dq):
        q = home.copy()
        q[j] += dq
        return q

    events = [[jump(0, 2.5)], [jump(1, 4.0)], [jump(0, 3.0), jump(0, -3.0)] * 5, [home + 100.0] * 5]

    def body(cell):
        states = []
        for ev in events:
            cell.ctl.absurd(ev)
            time.sleep(1.5)
            states.append(f"{cell.monitor.state()}{'*' if cell.monitor.ever_latched() else ''}")
        cell.monitor.wait_state("idle", 5.0)
        absurd_now = lambda: cell.ctl.absurd([jump(1, 4.0)])  # noqa: E731
        outs = _throws(cell, opts, lambda i: [(0.0, when_moving(cell, absurd_now))])
        fig = {**blocked_summary(outs), "states_after_events": states,  # '*': latched
               "state_after": cell.monitor.state()}  # fmt: skip
        return fig, ["latched after one absurd packet"] if states[0].endswith("*") else []

    return _run("absurd_feedback", ctx, opts, body, latch_allowed=True, replies=False)


@scenario("seqno_reset", "seqno restarts from 0 (tm continues) at rest and in motion")
def seqno_reset(ctx, opts):
    def body(cell):
        t0 = time.time()
        cell.ctl.reset_seqno()
        time.sleep(0.5)
        hooks = lambda i: [(0.0, when_moving(cell, cell.ctl.reset_seqno, delay=0.1))]  # noqa: E731
        outs = _throws(cell, opts, hooks)
        modes = cell.monitor.modes_between(t0, time.time())
        fails = [] if all(o.executed for o in outs) else ["a throw was not executed"]
        if "brake" in modes:
            fails.append("the daemon braked")
        return {**blocked_summary(outs), "modes": sorted(set(modes))}, fails

    return _run("seqno_reset", ctx, opts, body)
