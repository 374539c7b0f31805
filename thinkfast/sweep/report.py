"""A sweep's results as a table (CSV, JSON, terminal) and a plot (docs/SWEEPS.md)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

from thinkfast.config import to_dict
from thinkfast.sweep.spec import Sweep
from thinkfast.sweep.store import SweepStore, write_atomic

COLUMNS = (
    "point", "planner", "throws", "blocked", "rate", "ci95_lo", "ci95_hi", "rate_of_feasible",
    "reference", "difference", "diff_ci95_lo", "diff_ci95_hi", "p_exact", "p_reference_better",
    "starts_before_release", "start_median_s", "tree_key", "point_key",
)  # fmt: skip


def table_rows(sweep: Sweep, docs: list[dict]) -> list[dict[str, Any]]:
    """One row per point and planner: the swept values, rate and interval, the paired
    difference from the reference with its interval and exact McNemar p (empty for the
    reference itself)."""
    rows = []
    for doc in docs:
        s = doc["summary"]
        pairs = s.get("paired", {}).get("planners", {})
        for p, e in s["planners"].items():
            d = pairs.get(p, {}).get("overall")
            row = {"point": doc["index"], **{k: doc["params"].get(k) for k in sweep.axes}}
            row.update(
                planner=p, throws=e["throws"], blocked=e["blocked"], rate=e["rate"],
                ci95_lo=e["ci95"][0], ci95_hi=e["ci95"][1],
                rate_of_feasible=e.get("rate_of_feasible", ""), reference=sweep.reference,
                difference=d["difference"] if d else "",
                diff_ci95_lo=d["ci95"][0] if d else "", diff_ci95_hi=d["ci95"][1] if d else "",
                p_exact=d["p_exact"] if d else "",
                p_reference_better=d["p_reference_better"] if d else "",
                starts_before_release=e["starts_before_release"],
                start_median_s=e["start_median_s"], tree_key=doc["tree_key"][:16],
                point_key=doc["point_key"][:16],
            )  # fmt: skip
            rows.append(row)
    return rows


def write_results(sweep: Sweep, store: SweepStore, docs: list[dict]) -> dict[str, Path]:
    """``results.csv`` (:func:`table_rows`) and ``results.json`` (the sweep's settings and axes,
    every point's full summary) in the store; returns their paths."""
    rows = table_rows(sweep, docs)
    fields = ["point", *sweep.axes, *COLUMNS[1:]]
    csv_path, json_path = store.root / "results.csv", store.root / "results.json"
    store.root.mkdir(parents=True, exist_ok=True)
    with open(csv_path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(v) for k, v in r.items()})
    doc = {
        "sweep": str(sweep.path),
        "settings": to_dict(sweep.settings),
        "reference": sweep.reference,
        "axes": sweep.axes,
        "points": docs,
    }
    write_atomic(json_path, json.dumps(doc, indent=1).encode("utf-8"))
    return {"csv": csv_path, "json": json_path}


def _cell(v: Any) -> Any:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    if isinstance(v, list | tuple):
        return json.dumps(v)
    return v


def format_table(sweep: Sweep, docs: list[dict]) -> str:
    """The sweep as text: a line per point with every planner's rate and the difference from
    the reference [points] with its 95 % interval."""
    w = max(len(p) for p in sweep.settings.planners)
    feints = sum(t.kind == "feint" for t in sweep.throws)
    lines = [
        f"{len(docs)} points, {len(sweep.throws) - feints} throws"
        + (f" and {feints} feints" if feints else "")
        + f" each (seed {sweep.settings.seed}); rate [95 % Wilson]; vs {sweep.reference}: "
        "difference in points [95 % Newcombe], exact McNemar p",
    ]
    for doc in docs:
        s = doc["summary"]
        pairs = s.get("paired", {}).get("planners", {})
        lines.append("")
        vals = ", ".join(f"{k} = {_short(doc['params'][k])}" for k in sweep.axes) or "(base)"
        lines.append(f"point {doc['index']}: {vals}")
        for p, e in s["planners"].items():
            lo, hi = e["ci95"]
            text = f"  {p:<{w}} {100 * e['rate']:5.1f} % [{100 * lo:5.1f}, {100 * hi:5.1f}]"
            d = pairs.get(p, {}).get("overall")
            if d:
                dl, dh = d["ci95"]
                text += (f"  {100 * d['difference']:+5.1f} [{100 * dl:+5.1f}, {100 * dh:+5.1f}]"
                         f"  p {d['p_exact']:.2g}")  # fmt: skip
            lines.append(text)
    return "\n".join(lines)


def _short(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def plot_sweep(sweep: Sweep, docs: list[dict], path: str | Path) -> None:
    """Rate against each swept key (one panel per key), every planner with its 95 % Wilson
    interval; points that share the other keys' values are joined by a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    keys = list(sweep.axes) or ["point"]
    planners = list(sweep.settings.planners)
    fig, axes = plt.subplots(1, len(keys), figsize=(5.0 * len(keys), 4.2), squeeze=False)
    for ax, key in zip(axes[0], keys, strict=True):
        values = sweep.axes.get(key, [d["index"] for d in docs])
        labels = [json.dumps(v) if not isinstance(v, int | float) else _short(v) for v in values]
        uniq = list(dict.fromkeys(labels))
        numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
        span = (max(values) - min(values)) if numeric and len(values) > 1 else 1.0
        groups: dict[tuple, list[dict]] = {}
        for d in docs:
            rest = tuple(json.dumps(d["params"].get(k)) for k in sweep.axes if k != key)
            groups.setdefault(rest, []).append(d)
        for j, p in enumerate(planners):
            offset = (j - (len(planners) - 1) / 2) * 0.012 * span
            colour = f"C{j}"
            for g, (_, members) in enumerate(sorted(groups.items())):
                xs, ys, err = [], [], []
                for d in members:
                    v = d["params"].get(key, d["index"])
                    x = v if numeric else uniq.index(json.dumps(v)) / max(len(uniq) - 1, 1)
                    e = d["summary"]["planners"][p]
                    xs.append(float(x) + offset)
                    ys.append(e["rate"])
                    err.append(
                        (max(e["rate"] - e["ci95"][0], 0.0), max(e["ci95"][1] - e["rate"], 0.0))
                    )
                order = np.argsort(xs)
                ax.errorbar(
                    np.array(xs)[order], np.array(ys)[order],
                    yerr=np.array(err)[order].T, fmt="o-", capsize=3, color=colour, lw=0.8,
                    alpha=1.0 if g == 0 else 0.5, label=p if g == 0 else None,
                )  # fmt: skip
        if not numeric:
            ax.set_xticks([i / max(len(uniq) - 1, 1) for i in range(len(uniq))], uniq)
        ax.set(xlabel=key, ylabel="blocked (95 % Wilson)", ylim=(0, 1))
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(
        f"{len(sweep.throws)} throws per point (seed {sweep.settings.seed}); lines join points "
        "that share the other keys' values", fontsize=9,
    )  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
