"""Closed-loop statistics: many throws, every planner on the same throws, in lockstep.

Throw ``i`` of seed ``s`` is the same throw (and the same camera noise) for every planner, so the
comparison is paired. Work is split over processes by throw; results do not depend on the number
of processes.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from typing import Any

import numpy as np

from thinkfast.sim.lockstep import Outcome, World, simulate, wilson

BINS = (0.4, 0.5, 0.6, 0.7, 0.8)  # flight-time bins [s]
_W: dict[str, Any] = {}


def _init(make_world: Callable[[], World]) -> None:
    _W["world"] = make_world()


def _one(job: tuple) -> list[Outcome]:
    throw, planners, seed = job
    return [simulate(_W["world"], throw, p, seed) for p in planners]


def run_bench(make_world, throws, planners, seed: int, jobs: int = 1, progress=None) -> list:
    """Outcomes (one per throw and planner) in throw order.

    Args:
        make_world: builds the :class:`World` (called once per process).
        throws: the throws.
        planners: planner names ("tree", "naive", "oracle").
        seed: camera-noise seed base (throw i uses seed * 100003 + i).
        jobs: processes.
        progress: called with (done, total).
    """
    items = [(t, tuple(planners), seed * 100_003 + i) for i, t in enumerate(throws)]
    out: list[Outcome] = []
    if jobs > 1:
        ctx = mp.get_context("fork")
        with ctx.Pool(jobs, _init, (make_world,)) as pool:
            for k, res in enumerate(pool.imap(_one, items, chunksize=4)):
                out += res
                if progress:
                    progress(k + 1, len(items))
    else:
        _init(make_world)
        for k, item in enumerate(items):
            out += _one(item)
            if progress:
                progress(k + 1, len(items))
    return out


def summarize(outcomes: list[Outcome], planners) -> dict:
    """Per planner: blocked, rate, Wilson interval, per flight-time bin, share of feasible."""
    by = {p: [o for o in outcomes if o.planner == p] for p in planners}
    n = len(next(iter(by.values()))) if by else 0
    feasible = None
    if "oracle" in by:
        feasible = np.array([o.blocked for o in by["oracle"]])
    summary: dict[str, Any] = {"throws": n, "planners": {}}
    for p, rows in by.items():
        blocked = np.array([o.blocked for o in rows])
        flight = np.array([o.flight_time for o in rows])
        k = int(blocked.sum())
        lo, hi = wilson(k, n)
        entry = {
            "blocked": k,
            "rate": k / n if n else float("nan"),
            "ci95": [lo, hi],
            "why": {w: sum(1 for o in rows if o.why == w) for w in ("blocked", "late", "missed")},
        }
        bins = []
        for a, b in zip(BINS[:-1], BINS[1:], strict=True):
            sel = (flight >= a) & (flight < b + (1e-9 if b == BINS[-1] else 0.0))
            kb = int(blocked[sel].sum())
            bins.append(
                {
                    "flight_s": [a, b],
                    "throws": int(sel.sum()),
                    "blocked": kb,
                    "rate": kb / sel.sum() if sel.sum() else float("nan"),
                }
            )
        entry["by_flight_time"] = bins
        starts = np.array([o.start for o in rows])
        entry["false_starts"] = int(np.sum(starts < 0.0))  # moved while the ball was in the hand
        moved = starts[np.isfinite(starts) & (starts >= 0.0)]
        entry["start_median_s"] = float(np.median(moved)) if len(moved) else float("nan")
        if feasible is not None:
            nf = int(feasible.sum())
            kf = int((blocked & feasible).sum())
            entry["feasible"] = nf
            entry["rate_of_feasible"] = kf / nf if nf else float("nan")
            entry["ci95_of_feasible"] = list(wilson(kf, nf))
        summary["planners"][p] = entry
    return summary


def format_summary(summary: dict) -> str:
    """The summary as a table."""
    lines = [
        f"{summary['throws']} throws per planner (paired: same throws, same camera noise)",
        "",
        f"{'planner':<8} {'blocked':>8} {'rate':>7} {'95% CI':>15} {'of feasible':>12}",
    ]
    for p, e in summary["planners"].items():
        lo, hi = e["ci95"]
        extra = (
            f"  false starts {e['false_starts']}, median start {1e3 * e['start_median_s']:.0f} ms"
        )
        feas = f"{100 * e['rate_of_feasible']:.1f} %" if "rate_of_feasible" in e else "-"
        lines.append(
            f"{p:<8} {e['blocked']:>8} {100 * e['rate']:>6.1f}% "
            f"[{100 * lo:5.1f}, {100 * hi:5.1f}] {feas:>12}{extra}"
        )
    lines += ["", "by flight time (blocked / throws):"]
    head = "".join(
        f"{f'{b[0]:.1f}-{b[1]:.1f} s':>14}"
        for b in [x["flight_s"] for x in next(iter(summary["planners"].values()))["by_flight_time"]]
    )
    lines.append(f"{'planner':<8}{head}")
    for p, e in summary["planners"].items():
        cells = "".join(
            f"{str(x['blocked']) + '/' + str(x['throws']):>14}" for x in e["by_flight_time"]
        )
        lines.append(f"{p:<8}{cells}")
    return "\n".join(lines)


def plot_summary(summary: dict, path: str) -> None:
    """Success rate per flight-time bin and overall, with 95 % intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.8 / max(len(summary["planners"]), 1)
    for k, (p, e) in enumerate(summary["planners"].items()):
        rates = [x["rate"] for x in e["by_flight_time"]]
        xs = np.arange(len(rates)) + k * width
        ax.bar(xs, rates, width, label=f"{p} ({100 * e['rate']:.0f} %)")
    labels = [
        f"{x['flight_s'][0]:.1f}-{x['flight_s'][1]:.1f}"
        for x in next(iter(summary["planners"].values()))["by_flight_time"]
    ]
    ax.set_xticks(np.arange(len(labels)) + 0.4 - width / 2, labels)
    ax.set(
        xlabel="flight time [s]",
        ylabel="blocked",
        ylim=(0, 1),
        title=f"{summary['throws']} throws per planner (lockstep)",
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
