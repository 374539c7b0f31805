"""Scenarios of a faulty arm and controller: silences, an arm that stops following, controller
pauses and a soft servo through ordinary throws (each planner), and the fault-free baseline."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from bench.faultkit import rows as R
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
from thinkfast.sim.controller import ServoConfig

ABANDON = ("brake", "returning", "fault")
SILENCES = (0.1, 0.5, 2.0)


def _run(name, ctx, opts, body, planner="tree", servo=ServoConfig(), **finish_kw):
    t_start = time.time()
    cell = Cell(ctx, planner=planner, servo=servo, seed=ctx.seed)
    try:
        cell.start()
        figures, failures = body(cell)
        return finish(name, cell, t_start, figures, failures, opts=opts, **finish_kw)
    except Exception as exc:
        cell.close()
        return error_result(name, t_start, exc)


def _silence_figures(cell: Cell, events: list[tuple[float, float]]) -> dict:
    """Per silence: the first command after it vs the measured state (checker's resyncs)."""
    out = {}
    for seconds, t_end in events:
        rs = [r for r in cell.checker.resyncs if t_end - 0.05 <= r["t"] <= t_end + 0.5]
        out[f"{seconds:g}s"] = {k: v for k, v in rs[0].items() if k != "t"} if rs else None
    return out


@scenario("silence_rest", "the controller stops sending for 0.1, 0.5, 2 s with the arm at rest")
def silence_rest(ctx, opts):
    def body(cell):
        events = []
        for seconds in SILENCES[-1:] if opts.quick else SILENCES:  # quick: the longest
            cell.ctl.gap(seconds)
            time.sleep(seconds + 1.0)
            events.append((seconds, cell.ctl.gap_log[-1][1]))
        out = cell.throw(easy_throw(0), 0)
        cell.feed()
        fig = {"silences": _silence_figures(cell, events), "next_throw_executed": out.executed}
        return fig, [] if out.executed else ["the throw after the silences was not executed"]

    return _run("silence_rest", ctx, opts, body)


@scenario("silence_motion", "the controller stops sending for 0.1, 0.5, 2 s while the arm moves")
def silence_motion(ctx, opts):
    def body(cell):
        events = []
        for i, seconds in enumerate(SILENCES[:1] if opts.quick else SILENCES):
            cell.throw(far_throw(i), i, [(0.0, when_moving(cell, lambda s=seconds: cell.ctl.gap(s),
                                                           delay=0.1))])  # fmt: skip
            if cell.ctl.gap_log:
                events.append((seconds, cell.ctl.gap_log[-1][1]))
            cell.monitor.wait_state("idle", 6.0)
        out = cell.throw(easy_throw(0), 10)
        cell.feed()
        fig = {"silences": _silence_figures(cell, events), "next_throw_executed": out.executed,
               "state_after": cell.monitor.state()}  # fmt: skip
        return fig, [] if out.executed else ["the throw after the silences was not executed"]

    return _run("silence_motion", ctx, opts, body)


@scenario("arm_stops_following", "the servo freezes 0.6 s in motion: brake, recover, next throw")
def arm_stops_following(ctx, opts):
    def body(cell):
        home = ctx.robot.home
        freeze = [(0.0, when_moving(cell, lambda: cell.ctl.freeze(0.6)))]
        t0 = time.time()
        cell.throw(far_throw(0), 0, freeze, settle=8.0)
        braked = "brake" in cell.monitor.modes_between(t0, time.time())
        idle = cell.monitor.wait_state("idle", 8.0)
        time.sleep(0.5)
        _, q = cell.ctl.history(time.time() - 0.1)
        at_home = bool(len(q)) and float(np.max(np.abs(q[-1] - home))) < 0.01
        latched_1 = cell.monitor.ever_latched()
        nxt = cell.throw(easy_throw(0), 1)
        fig = {"braked": braked, "back_idle": idle, "back_home": at_home,
               "next_throw_executed": nxt.executed, "next_blocked": nxt.result.blocked,
               "latched_after_one": latched_1}  # fmt: skip
        fails = [w for w, ok in (("no brake", braked), ("not back to idle", idle),
                                 ("not back home", at_home),
                                 ("next throw not executed", nxt.executed),
                                 ("latched after one fault", not latched_1)) if not ok]  # fmt: skip
        if not opts.quick:  # repeated faults: when does a fault latch (a figure)
            fig["latched_after"] = None
            for k in range(2, 5):
                cell.throw(far_throw(k), k, freeze, settle=8.0)
                cell.monitor.wait_state(("idle", "fault"), 8.0)
                if cell.monitor.ever_latched():
                    fig["latched_after"] = k
                    break
        return fig, fails

    return _run("arm_stops_following", ctx, opts, body, latch_allowed=True, replies=False)


def _throw_series(name, ctx, opts, planner, servo=ServoConfig(), pauses=False):
    """``opts.throws`` ordinary throws; with ``pauses``: controller pauses of 60-200 ms at random
    (mean 2 s apart) and one in each throw between its first frame and 0.25 s before the
    crossing. A throw is lost to a pause when the daemon braked, returned or faulted between the
    pause and the crossing although the pause ended >= 100 ms before the crossing. A latched
    fault ends the series (it fails; ``latched_at_throw`` says when)."""

    def body(cell):
        rng = np.random.default_rng(ctx.seed)
        if pauses:
            cell.ctl.random_pauses(2.0, 0.06, 0.2)
        outs, at_risk, lost, lost_ids, latched_at, lost_detail = [], 0, 0, [], None, []
        for i, th in enumerate(sampled_throws(ctx, 2 if opts.quick else opts.throws)):
            hooks = []
            if pauses:
                cross = th.flight_time
                t = float(rng.uniform(-th.t_release, max(-th.t_release, cross - 0.25)))
                d = float(rng.uniform(0.06, 0.2))
                hooks = [(t, lambda d=d: cell.ctl.gap(d, R.PAUSE))]
            n_log = len(cell.ctl.gap_log)
            o = cell.throw(th, i, hooks)
            outs.append(o)
            for w0, w1, _ in cell.ctl.gap_log[n_log:] if pauses else []:
                if o.t_first - 0.5 <= w1 <= o.t_cross - 0.1:
                    at_risk += 1
                    modes = cell.monitor.modes_between(max(w0, o.t_first), o.t_cross)
                    if any(m in ABANDON for m in modes):
                        lost += 1
                        lost_ids.append(th.id)
                        since = o.t_first  # times below: seconds after the first frame
                        lost_detail.append({
                            "id": th.id, "modes": modes, "cross_s": round(o.t_cross - since, 3),
                            "pause_s": [round(w0 - since, 3), round(w1 - since, 3)],
                            "abandon_s": round(cell.monitor.first_mode_after(
                                ABANDON, max(w0, o.t_first)) - since, 3),
                        })  # fmt: skip
                        break
            if cell.monitor.ever_latched():  # the verdict is in: no point in waiting out the rest
                latched_at = i + 1
                break
        fig = {**blocked_summary(outs), "latched_at_throw": latched_at}
        fails = []
        if pauses:
            fig.update({"pauses": len(cell.ctl.gap_log), "throws_with_pause_before_crossing":
                        at_risk, "lost_to_pause": lost, "lost_ids": lost_ids[:10],
                        "lost_detail": lost_detail[:5]})  # fmt: skip
            if lost:
                fails.append(f"{lost} throws lost to a pause that ended before the crossing")
        return fig, fails

    return _run(name, ctx, opts, body, planner=planner, servo=servo)


SOFT = dataclasses.replace(ServoConfig(), tau_v=0.03, delay=0.024, lowpass_hz=20 / 3, kp=20 / 3)

for _p in ("tree", "naive"):
    scenario(f"baseline_{_p}", f"ordinary throws, no fault ({_p} planner): the reference")(
        lambda ctx, opts, p=_p: _throw_series(f"baseline_{p}", ctx, opts, p)
    )
    scenario(f"pauses_{_p}", f"controller pauses of 60-200 ms now and then ({_p} planner)")(
        lambda ctx, opts, p=_p: _throw_series(f"pauses_{p}", ctx, opts, p, pauses=True)
    )
    scenario(f"soft_servo_{_p}", f"servo time constants and lag 3x ServoConfig's ({_p} planner)")(
        lambda ctx, opts, p=_p: _throw_series(f"soft_servo_{p}", ctx, opts, p, servo=SOFT)
    )


MAX_INTERVENED = 0.001  # share of the supervisor's ticks it may change with a jittering clock


@scenario("clock_jitter", "tm jitters +-1 ms in whole ms and repeats; 10-50 ms controller stalls")
def clock_jitter(ctx, opts):
    """A controller that is not hard real-time (a virtual controller): ``tm`` +-1 ms around the
    cycle, rounded to whole ms, 1 % repeats; stalls of 10-50 ms (mean 1 s apart) after which
    ``tm`` has jumped while its servo moved one cycle. The supervisor changes fewer than
    :data:`MAX_INTERVENED` of the requests, and the commands pass the usual checks."""

    def body(cell):
        from thinkfast.sim.controller import ClockJitter

        cell.ctl.jitter(ClockJitter(seed=ctx.seed), (1.0, 0.01, 0.05))
        outs = [cell.throw(th, i) for i, th in
                enumerate(sampled_throws(ctx, 2 if opts.quick else opts.throws))]  # fmt: skip
        iv = cell.status().get("interventions") or {}
        ticks, changed = iv.get("ticks") or 0, iv.get("intervened") or 0
        share = changed / ticks if ticks else None
        fig = {**blocked_summary(outs), "pauses": len(cell.ctl.gap_log),
               "supervisor_ticks": ticks, "intervened": changed,
               "intervened_pct": None if share is None else round(100.0 * share, 4)}  # fmt: skip
        # executed and blocked are reported, not judged here: as in baseline_tree, a throw may
        # go unexecuted on the exact clock too (seed 1's 17th comes while the arm is still on
        # its way home from the 16th); the jitter's cost in blocks is judged against
        # baseline_tree, the same throws on the exact clock
        fails = []
        if share is None or share >= MAX_INTERVENED:
            fails.append(f"supervisor changed {changed} of {ticks} ticks")
        return fig, fails

    return _run("clock_jitter", ctx, opts, body)
