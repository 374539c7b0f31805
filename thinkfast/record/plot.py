"""``thinkfast-sim record info`` and ``record plot``: a flight record summarised and drawn.

:func:`record_info` gives lines of text (attributes, streams, throws, EGM rate);
:func:`plot_record` draws one PNG: the joints (commanded and measured), the ball track against
the filter's belief (accepted detections and the belief's mean with its 2-sigma band, per axis),
the predicted crossing point on the plane, and the decisions over time (value, mode).
"""

from __future__ import annotations

import datetime
from collections import Counter
from pathlib import Path

import numpy as np

from thinkfast.record.format import MODES, Record
from thinkfast.record.tables import break_at_gaps, columns, event_times

CROSS_SD = 0.5  # m: crossing predictions with a larger standard deviation are not drawn
GAP = 0.5  # s: ball, belief, crossing and decision rows further apart are not joined


def record_info(record: Record) -> list[str]:
    """Lines describing ``record``: file, schema, attributes, rows per stream, events."""
    a = record.attrs
    started = a.get("started")
    when = (
        datetime.datetime.fromtimestamp(started).isoformat(sep=" ", timespec="seconds")
        if isinstance(started, int | float)
        else "?"
    )
    complete = {True: "yes", False: "no (partial)", None: "n/a (schema 1)"}[record.complete]
    lines = [
        f"{record.path}: thinkfast-record schema {record.version}, complete {complete}",
        f"  planner {a.get('planner', '?')}, started {when}, "
        f"tree config {str(a.get('tree_config_sha256', ''))[:16] or '?'}",
    ]
    times = [record.raw_t] + [record.tables[n][:, 0] for n in record.tables]
    times = [t for t in times if len(t)]
    if times:
        t0 = min(float(t.min()) for t in times)
        t1 = max(float(t.max()) for t in times)
        lines.append(f"  span {t1 - t0:.2f} s")
    lines.append(f"  raw {len(record.raw_t)} payloads")
    for name, table in record.tables.items():
        extra = ""
        if name == "egm" and len(table) > 1:
            dt = np.diff(table[:, 0])
            extra = f" ({1.0 / np.median(dt):.0f} Hz median)" if np.median(dt) > 0 else ""
        lines.append(f"  {name} {len(table)} rows{extra}")
    kinds = Counter(e.kind for e in record.events)
    if kinds:
        lines.append("  events " + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items())))
    else:
        lines.append("  events none")
    return lines


def plot_record(record: Record, png: Path) -> None:
    """Draw ``record`` into ``png`` (module doc)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e, d = columns(record, "egm"), columns(record, "detections")
    b, dec = columns(record, "beliefs"), columns(record, "decisions")
    t0 = _origin(record)
    fig, ax = plt.subplots(4, 1, figsize=(11, 13), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j in range(6):
        c = colours[j % len(colours)]
        ax[0].plot(e["t"] - t0, e["q_cmd"][:, j], color=c, lw=1.2, label=f"joint {j + 1}")
        ax[0].plot(e["t"] - t0, e["q_fb"][:, j], color=c, lw=0.8, ls="--")
    ax[0].set_ylabel("joint [rad]")
    ax[0].set_title("joints: commanded (solid), measured (dashed)")
    ax[0].legend(ncol=6, fontsize=8, loc="lower left")
    for k, axis in enumerate("xyz"):
        c = colours[k]
        ax[1].plot(d["t_recv"] - t0, d[axis], ".", ms=3, color=c, label=f"{axis} detected")
        if len(b["t"]):
            sd = np.sqrt(np.clip(b["cov"][:, 7 * k], 0.0, None))
            tb, m, sd = break_at_gaps(b["t"] - t0, b["mean"][:, k], sd, gap=GAP)
            ax[1].plot(tb, m, color=c, lw=1, label=f"{axis} belief")
            ax[1].fill_between(tb, m - 2 * sd, m + 2 * sd, color=c, alpha=0.2)
    ax[1].set_ylabel("ball [m] (base)")
    ax[1].set_title("ball track: accepted detections against the belief (mean, 2 sigma)")
    ax[1].legend(ncol=6, fontsize=8, loc="upper right")
    ok = b["crossing_ok"] > 0.5
    if len(b["t"]):  # a ball held still "crosses" far away, with metres of spread: left out
        ok &= np.sqrt(np.clip(np.maximum(b["o_cov"][:, 0], b["o_cov"][:, 4]), 0, None)) < CROSS_SD
    for k, name in enumerate(("Y", "Z")):
        sd = np.sqrt(np.clip(b["o_cov"][ok, 4 * k], 0.0, None))
        tc, m, sd = break_at_gaps(b["t"][ok] - t0, b["o_mean"][ok, k], sd, gap=GAP)
        ax[2].plot(tc, m, ".-", ms=3, color=colours[k], label=f"{name} at plane")
        ax[2].fill_between(tc, m - 2 * sd, m + 2 * sd, color=colours[k], alpha=0.2)
    ax[2].set_ylabel("crossing [m]")
    ax[2].set_title(
        f"predicted crossing point on the plane (mean, 2 sigma; where sigma < {CROSS_SD:g} m)"
    )
    ax[2].legend(fontsize=8, loc="upper right")
    td, value, mode = decision_steps(dec, t0)
    ax[3].step(td, value, where="post", color=colours[0], label="value")
    ax[3].set_ylabel("value (block probability)")
    ax[3].set_ylim(-0.05, 1.05)
    twin = ax[3].twinx()
    twin.step(td, mode, where="post", color=colours[1], lw=0.8, label="mode")
    twin.set_yticks(range(len(MODES)), MODES, fontsize=8)
    twin.set_ylim(-0.5, len(MODES) - 0.5)
    for t, ev in zip(event_times(record), record.events, strict=True):
        if ev.kind in ("throw_start", "throw_end"):
            ax[3].axvline(t - t0, color="grey", lw=0.6, ls=":")
    ax[3].set_title("decisions: value of the chosen motion, mode (dotted: throw start/end)")
    ax[3].set_xlabel(f"time [s] since {t0:.3f} (Unix)")
    fig.suptitle(f"{record.path.name}: planner {record.attrs.get('planner', '?')}")
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    plt.close(fig)


def decision_steps(dec: dict, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times [s] since ``t0``, values and modes of the decisions, drawn as steps held until
    the next decision: decisions come with detections, so each step ends at most ``GAP`` after
    its decision (a NaN row), never through an idle stretch to the next throw."""
    t, value, mode = np.asarray(dec["t"], float) - t0, dec["value"], dec["mode"]
    if len(t) == 0:
        return t, np.asarray(value, float), np.asarray(mode, float)
    end = np.append(np.diff(t) > GAP, True)  # the last decision before a gap (or the end)
    at = np.flatnonzero(end) + 1
    t_end = t[end] + np.minimum(GAP, 0.02)  # a decision holds until the next detection
    return (
        np.insert(t, at, t_end),
        np.insert(np.asarray(value, float), at, np.nan),
        np.insert(np.asarray(mode, float), at, np.nan),
    )


def _origin(record: Record) -> float:
    """The earliest time in the record [s] (0 for an empty one)."""
    firsts = [float(t[0]) for t in (record.raw_t, *(v[:, 0] for v in record.tables.values()))
              if len(t)]  # fmt: skip
    return min(firsts) if firsts else 0.0
