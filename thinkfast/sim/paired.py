"""Every planner against a reference planner, paired on the same throws (bench section ``paired``).

Only released throws count (a feint cannot be blocked). A throw is paired when both planners
ran it: outcomes are matched by throw id and by how often that id occurred before, so a throw
set that repeats an id still pairs the k-th occurrence with the k-th. Statistics:
:func:`thinkfast.sim.stats.compare` (counts, difference with Newcombe's interval, exact McNemar),
overall, per kind of throw and per flight-time bin.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from thinkfast.sim.stats import compare
from thinkfast.sim.thrower import KINDS

METHOD = {
    "difference": "rate of the planner minus rate of the reference, on the paired throws",
    "ci95": "Newcombe (1998) method 10: square-and-add of Wilson score intervals, paired",
    "p_exact": "exact McNemar: two-sided binomial test of the discordant throws, p = 1/2",
    "p_reference_better": "exact McNemar, one-sided: the reference blocks more often",
}


def _keyed(rows) -> dict[tuple[str, int], Any]:
    """Released throws of one planner by (throw id, occurrence of that id)."""
    seen: dict[str, int] = {}
    out = {}
    for o in rows:
        k = seen.get(o.throw_id, 0)
        seen[o.throw_id] = k + 1
        if o.kind != "feint":
            out[(o.throw_id, k)] = o
    return out


def paired_summary(
    outcomes, planners: Sequence[str], reference: str, bins: Sequence[float]
) -> dict:
    """Paired comparison of every planner with ``reference``.

    Args:
        outcomes: :class:`~thinkfast.sim.lockstep.Outcome` rows of a bench run, any order.
        planners: planner names in report order; ``reference`` must be one of them.
        reference: the planner every other one is compared with.
        bins: flight-time bin edges [s] (the last bin includes its upper edge).

    Returns:
        ``{"reference", "method", "planners": {name: {"overall", "by_kind",
        "by_flight_time"}}}``; each entry is :func:`~thinkfast.sim.stats.compare`'s dict, a
        flight-time entry also has ``flight_s`` [s, s]. No entry for the reference itself.
    """
    if reference not in planners:
        raise ValueError(f"reference planner {reference!r} is not among {list(planners)}")
    rows = {p: _keyed(o for o in outcomes if o.planner == p) for p in planners}
    ref = rows[reference]
    result: dict[str, Any] = {"reference": reference, "method": METHOD, "planners": {}}
    for p in planners:
        if p == reference:
            continue
        keys = [k for k in ref if k in rows[p]]  # the reference's (throw) order

        def cmp(sel, p=p, keys=keys):
            ks = [k for k in keys if sel(ref[k])]
            return compare([ref[k].blocked for k in ks], [rows[p][k].blocked for k in ks])

        kinds = [k for k in KINDS if k != "feint" and any(ref[x].kind == k for x in keys)]
        flight = []
        for lo, hi in zip(bins[:-1], bins[1:], strict=True):
            top = hi + (1e-9 if hi == bins[-1] else 0.0)
            entry = cmp(lambda o, lo=lo, top=top: lo <= o.flight_time < top)
            flight.append({"flight_s": [lo, hi], **entry})
        result["planners"][p] = {
            "overall": cmp(lambda o: True),
            "by_kind": {k: cmp(lambda o, k=k: o.kind == k) for k in kinds},
            "by_flight_time": flight,
        }
    return result


def _line(label: str, e: dict, w: int) -> str:
    lo, hi = e["ci95"]
    if e["throws"]:
        diff = f"{100 * e['difference']:+6.1f} [{100 * lo:+6.1f}, {100 * hi:+6.1f}]"
    else:
        diff = f"{'-':>6} {'':>16}"
    return (
        f"{label:<{w}} {e['throws']:>6} {e['both']:>5} {e['only_reference']:>8} "
        f"{e['only_other']:>10} {e['neither']:>7}  {diff}  {e['p_exact']:>7.3g} "
        f"{e['p_reference_better']:>12.3g}"
    )


def format_paired(paired: dict) -> list[str]:
    """The ``paired vs <reference>`` section of the bench table (lines)."""
    ref, planners = paired["reference"], paired["planners"]
    if not planners:
        return []
    w = max([12, *(len(p) + 12 for p in planners)])
    head = (
        f"{'planner':<{w}} {'throws':>6} {'both':>5} {'only ref':>8} {'only other':>10} "
        f"{'neither':>7}  {'diff [95% CI] pts':>24}  {'p exact':>7} {'p ref better':>12}"
    )
    lines = [
        "",
        f"paired vs {ref} (released throws both ran; diff = planner - {ref}, points, "
        f"Newcombe interval; p: exact McNemar, two-sided and one-sided '{ref} better'):",
        head,
    ]
    lines += [_line(p, e["overall"], w) for p, e in planners.items()]
    lines += ["", f"paired vs {ref} by kind and flight time:", head]
    for p, e in planners.items():
        if len(e["by_kind"]) > 1:
            lines += [_line(f"{p} {k}", x, w) for k, x in e["by_kind"].items()]
        for x in e["by_flight_time"]:
            a, b = x["flight_s"]
            lines.append(_line(f"{p} {a:.1f}-{b:.1f} s", x, w))
    return lines


def plot_paired(ax, paired: dict) -> None:
    """Differences from the reference with 95 % intervals: overall and per kind, per planner."""
    ref, planners = paired["reference"], paired["planners"]
    labels, diffs, errs = [], [], []
    for p, e in planners.items():
        subsets = [("all", e["overall"])]
        if len(e["by_kind"]) > 1:
            subsets += list(e["by_kind"].items())
        for name, x in subsets:
            lo, hi = x["ci95"]
            d = 100 * x["difference"]
            labels.append(f"{p} {name}\np={x['p_exact']:.2g}")
            diffs.append(d)
            errs.append((d - 100 * lo, 100 * hi - d))
    ys = range(len(labels))
    ax.errorbar(diffs, ys, xerr=list(zip(*errs, strict=True)) if errs else None, fmt="o", capsize=3)
    ax.axvline(0.0, color="grey", lw=0.8)
    ax.set_yticks(list(ys), labels, fontsize=7)
    ax.invert_yaxis()
    ax.set(xlabel=f"blocked, minus {ref} [points]", title=f"paired vs {ref} (95 % Newcombe)")
