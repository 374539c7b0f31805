"""Closed-loop statistics: many throws, every planner on the same throws, in lockstep.

Throw ``i`` of seed ``s`` is the same throw (and the same camera noise) for every planner, so the
comparison is paired (``paired``: every planner against a reference, :mod:`thinkfast.sim.paired`).
Every throw is seeded by its index alone (:func:`throw_seed`), so work can be split over
processes, chunks of throws or machines (``thinkfast/sim/cluster.py``) with identical results.
"""

from __future__ import annotations

import math
import multiprocessing as mp
from collections.abc import Callable
from typing import Any

import numpy as np

from thinkfast.sim.lockstep import FEINT_WINDOW, Outcome, World, simulate
from thinkfast.sim.paired import format_paired, paired_summary, plot_paired
from thinkfast.sim.stats import wilson
from thinkfast.sim.thrower import KINDS

BINS = (0.4, 0.5, 0.6, 0.7, 0.8)  # flight-time bins [s]
_W: dict[str, Any] = {}


def _init(make_world: Callable[[], World]) -> None:
    _W["world"] = make_world()


def throw_seed(seed: int, index: int) -> int:
    """Camera-noise seed of the throw at ``index`` (0-based, in the bench's throw order)."""
    return seed * 100_003 + index


def _one(job: tuple) -> list[Outcome]:
    throw, planners, seed = job
    return [simulate(_W["world"], throw, p, seed) for p in planners]


def run_chunk(world: World, throws, planners, seed: int, start: int) -> list[Outcome]:
    """Outcomes of ``throws`` (the bench's throws ``start``, ``start + 1``, ...), every planner
    per throw, in throw order: the same rows :func:`run_bench` gives for them."""
    return [
        simulate(world, t, p, throw_seed(seed, start + k))
        for k, t in enumerate(throws)
        for p in planners
    ]


def run_bench(make_world, throws, planners, seed: int, jobs: int = 1, progress=None) -> list:
    """Outcomes (one per throw and planner) in throw order.

    Args:
        make_world: builds the :class:`World` (called once per process).
        throws: the throws.
        planners: planner names ("tree", "naive", "oracle").
        seed: camera-noise seed base (throw i uses :func:`throw_seed`, seed * 100003 + i).
        jobs: processes.
        progress: called with (done, total).
    """
    items = [(t, tuple(planners), throw_seed(seed, i)) for i, t in enumerate(throws)]
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


def summarize(outcomes: list[Outcome], planners, reference: str | None = None) -> dict:
    """Per planner: blocked, rate, Wilson interval, per flight-time bin, share of feasible, and
    per kind of throw (``by_kind``: still, windup, feint; see :func:`_kind_entry`); ``paired``:
    every planner against ``reference`` (default ``tree`` when it ran, else the first planner;
    :func:`~thinkfast.sim.paired.paired_summary`).

    The overall figures count throws only: a feint cannot be blocked (``feints`` counts them).
    ``starts_before_release`` (also as ``false_starts``): throws the arm left home for before
    their release; ``feint_starts``: feints it left home for at all.
    """
    by = {p: [o for o in outcomes if o.planner == p] for p in planners}
    first = next(iter(by.values())) if by else []
    n = sum(1 for o in first if o.kind != "feint")
    feasible = None  # aligned with every planner's rows (same throws, same order)
    if "oracle" in by:
        feasible = np.array([o.blocked for o in by["oracle"]], dtype=bool)
    kinds = [k for k in KINDS if any(o.kind == k for o in first)]
    summary: dict[str, Any] = {
        "throws": n,
        "feints": len(first) - n,
        "kinds": {k: sum(1 for o in first if o.kind == k) for k in kinds},
        "planners": {},
    }
    for p, all_rows in by.items():
        rows, ok = _select(all_rows, feasible, lambda k: k != "feint")
        entry = _rates(rows, ok)
        entry["why"] = {
            w: sum(1 for o in rows if o.why == w) for w in ("blocked", "late", "missed")
        }
        blocked = np.array([o.blocked for o in rows], dtype=bool)
        flight = np.array([o.flight_time for o in rows])
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
        entry["false_starts"] = entry["starts_before_release"]
        entry["by_kind"] = {
            k: _kind_entry(*_select(all_rows, feasible, lambda x, k=k: x == k)) for k in kinds
        }
        if "feint" in kinds:
            entry["feint_starts"] = entry["by_kind"]["feint"]["starts"]
        summary["planners"][p] = entry
    names = list(by)
    if reference is None:
        reference = "tree" if "tree" in by else (names[0] if names else None)
    if reference is not None:
        summary["paired"] = paired_summary(outcomes, names, reference, BINS)
    return summary


def _select(rows: list[Outcome], feasible: np.ndarray | None, keep) -> tuple[list, Any]:
    """The rows whose kind passes ``keep`` and their feasibility flags (or None)."""
    idx = [i for i, o in enumerate(rows) if keep(o.kind)]
    return [rows[i] for i in idx], (None if feasible is None else feasible[idx])


def _rates(rows: list[Outcome], feasible: np.ndarray | None) -> dict:
    """Blocked, rate, Wilson interval, starts before release, median start, share of feasible."""
    n = len(rows)
    blocked = np.array([o.blocked for o in rows], dtype=bool)
    k = int(blocked.sum())
    lo, hi = wilson(k, n)
    starts = np.array([o.start for o in rows])
    moved = starts[np.isfinite(starts) & (starts >= 0.0)]
    entry: dict[str, Any] = {
        "throws": n,
        "blocked": k,
        "rate": k / n if n else float("nan"),
        "ci95": [lo, hi],
        "starts_before_release": int(np.sum(starts < 0.0)),  # moved with the ball in the hand
        "start_median_s": float(np.median(moved)) if len(moved) else float("nan"),
    }
    if any(o.hedges for o in rows):  # the hedge stage ran (control/hedge.py): both starts
        commit = np.array([o.commit_start for o in rows])
        commit = commit[np.isfinite(commit)]
        entry["commit_start_median_s"] = float(np.median(commit)) if len(commit) else math.nan
        entry["hedged"] = int(sum(o.hedges > 0 for o in rows))
    if feasible is not None:
        nf, kf = int(feasible.sum()), int((blocked & feasible).sum())
        entry["feasible"] = nf
        entry["rate_of_feasible"] = kf / nf if nf else float("nan")
        entry["ci95_of_feasible"] = list(wilson(kf, nf))
    return entry


def _kind_entry(rows: list[Outcome], feasible: np.ndarray | None) -> dict:
    """One kind's figures: :func:`_rates` for throws; for feints (never released, so neither
    blocked nor missed) ``starts`` (the arm left home at all), the largest shield displacement
    from home per feint (``displacement_m``, its max and median) and how many were home again
    (1 cm, at rest) within ``FEINT_WINDOW`` of the ball stopping."""
    if not rows or rows[0].kind != "feint":
        return _rates(rows, feasible)
    disp = np.array([o.displacement for o in rows])
    back = np.array([o.home_after for o in rows])
    hedged = {"hedged": int(sum(o.hedges > 0 for o in rows))} if any(o.hedges for o in rows) else {}
    return {
        **hedged,
        "feints": len(rows),
        "starts": int(sum(o.moved for o in rows)),
        "starts_before_release": int(sum(o.moved for o in rows)),
        "displacement_m": [round(float(x), 4) for x in disp],
        "displacement_max_m": float(disp.max()),
        "displacement_median_m": float(np.median(disp)),
        "home_again": int(sum(o.home_again for o in rows)),
        "home_after_max_s": float(np.max(back)) if np.isfinite(back).all() else float("nan"),
        "home_window_s": FEINT_WINDOW,
    }


def format_summary(summary: dict) -> str:
    """The summary as a table."""
    w = max([8, *map(len, summary["planners"])])
    lines = [
        f"{summary['throws']} throws"
        + (f" and {summary['feints']} feints" if summary.get("feints") else "")
        + " per planner (paired: same throws, same camera noise)",
        "",
        f"{'planner':<{w}} {'blocked':>8} {'rate':>7} {'95% CI':>15} {'of feasible':>12}",
    ]
    for p, e in summary["planners"].items():
        lo, hi = e["ci95"]
        extra = (
            f"  false starts {e['false_starts']}, median start {1e3 * e['start_median_s']:.0f} ms"
        )
        if "commit_start_median_s" in e:
            extra += f" (committed {1e3 * e['commit_start_median_s']:.0f} ms, {e['hedged']} hedged)"
        feas = f"{100 * e['rate_of_feasible']:.1f} %" if "rate_of_feasible" in e else "-"
        lines.append(
            f"{p:<{w}} {e['blocked']:>8} {100 * e['rate']:>6.1f}% "
            f"[{100 * lo:5.1f}, {100 * hi:5.1f}] {feas:>12}{extra}"
        )
    lines += ["", "by flight time (blocked / throws):"]
    head = "".join(
        f"{f'{b[0]:.1f}-{b[1]:.1f} s':>14}"
        for b in [x["flight_s"] for x in next(iter(summary["planners"].values()))["by_flight_time"]]
    )
    lines.append(f"{'planner':<{w}}{head}")
    for p, e in summary["planners"].items():
        cells = "".join(
            f"{str(x['blocked']) + '/' + str(x['throws']):>14}" for x in e["by_flight_time"]
        )
        lines.append(f"{p:<{w}}{cells}")
    paired = format_paired(summary["paired"]) if "paired" in summary else []
    return "\n".join(lines + _format_kinds(summary, w) + paired)


def _format_kinds(summary: dict, w: int) -> list[str]:
    """The per-kind tables (planner column ``w`` wide): throws of each kind, then feints."""
    kinds = summary.get("kinds", {})
    lines = ["", "by kind (starts: the arm left home before the release):"]
    lines.append(
        f"{'planner':<{w}} {'kind':<7} {'throws':>6} {'blocked':>8} {'rate':>7} {'95% CI':>15} "
        f"{'starts':>7}"
    )
    for p, e in summary["planners"].items():
        for k, x in e["by_kind"].items():
            if k == "feint":
                continue
            lo, hi = x["ci95"]
            lines.append(
                f"{p:<{w}} {k:<7} {x['throws']:>6} {x['blocked']:>8} {100 * x['rate']:>6.1f}% "
                f"[{100 * lo:5.1f}, {100 * hi:5.1f}] {x['starts_before_release']:>7}"
            )
    if "feint" in kinds:
        window = next(iter(summary["planners"].values()))["by_kind"]["feint"]["home_window_s"]
        lines += [
            "",
            f"feints (never released): starts = the arm left home at all; shield displacement "
            f"from home; home again (1 cm, at rest) within {window:g} s of the ball stopping",
            f"{'planner':<{w}} {'feints':>6} {'starts':>7} {'max disp':>9} {'median':>8} "
            f"{'home again':>11}",
        ]
        for p, e in summary["planners"].items():
            x = e["by_kind"]["feint"]
            lines.append(
                f"{p:<{w}} {x['feints']:>6} {x['starts']:>7} {x['displacement_max_m']:>7.3f} m "
                f"{x['displacement_median_m']:>6.3f} m {x['home_again']:>6}/{x['feints']}"
            )
    return lines


def plot_summary(summary: dict, path: str) -> None:
    """Write :func:`summary_figure` to the PNG file ``path``."""
    import matplotlib.pyplot as plt

    fig = summary_figure(summary)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def bin_errors(bins: list[dict]) -> np.ndarray:
    """Error bar lengths (2, n_bins) below and above each flight-time bin's rate: its 95 %
    Wilson interval (0 for an empty bin)."""
    err = np.zeros((2, len(bins)))
    for i, x in enumerate(bins):
        if x["throws"]:
            lo, hi = wilson(x["blocked"], x["throws"])
            err[:, i] = (x["rate"] - lo, hi - x["rate"])
    return err


def summary_figure(summary: dict):
    """Success rate per flight-time bin with 95 % Wilson intervals and the throws per bin, and
    overall in the legend (left, legend below the panel); per kind of throw with 95 % intervals
    (middle; feints: what the arm did, in the panel's caption); paired differences (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = summary.get("paired", {}).get("planners")
    fig, (ax, axk, *axp) = plt.subplots(
        1, 3 if pairs else 2, figsize=(15 if pairs else 10, 5.0),
        gridspec_kw={"width_ratios": [2, 1, 1.2] if pairs else [2, 1]},
    )  # fmt: skip
    planners = summary["planners"]
    width = 0.8 / max(len(planners), 1)
    for k, (p, e) in enumerate(planners.items()):
        bins = e["by_flight_time"]
        rates = [x["rate"] if x["throws"] else 0.0 for x in bins]
        xs = np.arange(len(rates)) + k * width
        ax.bar(xs, rates, width, yerr=bin_errors(bins), capsize=2, label=f"{p} ({_pct(e)})")
    labels = [
        f"{x['flight_s'][0]:.1f}-{x['flight_s'][1]:.1f}\nn={x['throws']}"
        for x in next(iter(planners.values()))["by_flight_time"]
    ]
    ax.set_xticks(np.arange(len(labels)) + 0.4 - width / 2, labels)
    ax.set(
        xlabel="flight time [s] (n: throws per bin, the same for every planner)",
        ylabel="blocked (95 % Wilson)",
        ylim=(0, 1),
        title=f"{summary['throws']} throws per planner (lockstep)",
    )
    ax.legend(
        loc="upper center", bbox_to_anchor=(0.5, -0.24), ncol=min(len(planners), 4),
        frameon=False, fontsize=8,
    )  # fmt: skip
    kinds = [k for k in summary.get("kinds", {}) if k != "feint"]
    for j, (p, e) in enumerate(planners.items()):
        rates = np.array([e["by_kind"][k]["rate"] for k in kinds])
        ci = np.array([e["by_kind"][k]["ci95"] for k in kinds]).reshape(-1, 2)
        err = np.abs(ci.T - rates)
        axk.bar(np.arange(len(kinds)) + j * width, rates, width, yerr=err, capsize=3, label=p)
    counts = [f"{k}\n({summary['kinds'][k]})" for k in kinds]
    axk.set_xticks(np.arange(len(kinds)) + 0.4 - width / 2, counts)
    axk.set(ylabel="blocked", ylim=(0, 1), title="by kind (95 % Wilson)")
    if "feint" in summary.get("kinds", {}):
        text = ["feints: started / max shield displacement / home again"]
        for p, e in planners.items():
            x = e["by_kind"]["feint"]
            text.append(
                f"{p}: {x['starts']}/{x['feints']}, {100 * x['displacement_max_m']:.0f} cm, "
                f"{x['home_again']}/{x['feints']}"
            )
        axk.set_xlabel("\n".join(text), fontsize=8)
    if pairs:
        plot_paired(axp[0], summary["paired"])
    fig.tight_layout()
    return fig


def _pct(entry: dict) -> str:
    """Overall rate and its 95 % interval, e.g. ``61 % [57, 65]``."""
    lo, hi = entry["ci95"]
    return f"{100 * entry['rate']:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
