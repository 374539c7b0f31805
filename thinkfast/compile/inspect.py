"""Text and plots about compiled action trees: ``info``, ``diff`` and the diff figure.

Pure functions of :class:`~thinkfast.tree.action_tree.ActionTree` values (no argument parsing,
no file reading); the CLI loads the trees and prints what these return.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.compile.provenance_text import defect_line, meta_lines, provenance_diff
from thinkfast.tree.action_tree import EDGE_CUT, EDGE_REACHED, ActionTree
from thinkfast.tree.identity import ROBOT_KEYS, array_checksums, identity_changes, tree_fingerprint

GOAL_KEY_SCALE = 1e6  # goals of two trees are the same goal when (y, z) agree to 1e-6 m
ARRIVAL_TOL = 1e-6  # s: arrival times closer than this are unchanged (float noise, not a change)
MIN_COLOUR_SPAN = 1e-3  # s: the B - A colour scale spans at least +-1 ms (noise stays white)
# plane plots share the goal table's layout: y increasing to the right, as the thrower sees it
Y_LABEL = "base y [m] (robot's left +, seen from the thrower)"
LARGEST = 10


class TreeDiff(NamedTuple):
    """Result of :func:`tree_diff`.

    Attributes:
        same: True exactly when the fingerprints are equal: identical datasets and identity
            attributes (resolved parameters, robot files, ...: :mod:`thinkfast.tree.identity`).
            Versions, machine, creation time and config text may differ.
        text: the report, several lines.
    """

    same: bool
    text: str


def earliest_arrival(tree: ActionTree) -> np.ndarray:
    """Earliest arrival time at every goal over its terminal edges.

    Returns:
        arrival time from motion start [s], shape (G,); ``inf`` for a goal no terminal edge reaches.
    """
    out = np.full(len(tree.goal_yz), np.inf)
    np.minimum.at(out, tree.term_goal, tree.term_arrival)
    return out


def depth_counts(tree: ActionTree) -> np.ndarray:
    """Counts per depth: columns nodes, cut edges, reached edges, terminal edges.

    Returns:
        int64 array, shape (max_depth + 1, 4); row d counts the nodes at depth d, the edges into
        them by kind and the terminal edges leaving them.
    """
    depth = tree.node_depth
    n = tree.max_depth + 1
    into = depth[1:]
    kind = tree.edge_kind[1:]
    return np.stack(
        [
            np.bincount(depth, minlength=n),
            np.bincount(into[kind == EDGE_CUT], minlength=n),
            np.bincount(into[kind == EDGE_REACHED], minlength=n),
            np.bincount(depth[tree.term_node], minlength=n),
        ],
        axis=1,
    ).astype(np.int64)


def tree_info(tree: ActionTree) -> str:
    """Summary of a tree: fingerprint (as :func:`tree_diff` and the daemon's start log give it),
    counts per depth, goal coverage, arrival times, parameters, provenance."""
    counts = depth_counts(tree)
    ea = earliest_arrival(tree)
    covered = np.isfinite(ea)
    g, m = len(ea), len(tree.grid_yz)
    lines = [
        f"action tree: {tree.n_nodes} nodes, {tree.n_terminals} terminal edges,"
        f" max depth {tree.max_depth}, {len(tree.subgoal_goal)} steering sub-goals",
        f"fingerprint {tree_fingerprint(tree)[:16]} (the daemon's start log: tree_fingerprint)",
        f"goals: {int(covered.sum())} covered by a terminal edge / {g} reachable / {m} grid points",
        "",
        "  depth      nodes        cut    reached  terminals",
    ]
    for d, (nodes, cut, reached, terms) in enumerate(counts):
        edges = (f"{'-':>10} {'-':>10}") if d == 0 else f"{cut:>10} {reached:>10}"
        lines.append(f"  {d:>5} {nodes:>10} {edges} {terms:>10}")
    lines += ["", f"arrival time [s]{'min':>18} {'median':>8} {'p90':>8} {'max':>8}"]
    lines.append(_stats_row(f"terminal edges ({tree.n_terminals})", tree.term_arrival))
    lines.append(_stats_row(f"earliest per goal ({int(covered.sum())})", ea[covered]))
    missing = [_yz(tree.goal_yz[i]) for i in np.flatnonzero(~covered)]
    if missing:
        shown = ", ".join(missing[:LARGEST]) + (", ..." if len(missing) > LARGEST else "")
        lines.append(f"uncovered goals ({len(missing)}): {shown}")
    lines += ["", *shield_lines(tree)]
    lines += ["", *meta_lines(tree.meta)]
    return "\n".join(lines)


def shield_lines(tree: ActionTree) -> list[str]:
    """What the stored shield paths hold: spacing, samples per edge, the region they sweep."""
    dt = tree.meta.get("shield_dt")
    e, t = tree.edge_shield, tree.term_shield
    spacing = f"every {dt:g} s" if isinstance(dt, int | float) else "spacing not recorded"
    lines = [
        f"shield paths ({spacing}, coplanar normal +x): {e.shape[1]} samples per tree edge,"
        f" {t.shape[1]} per terminal edge"
    ]
    pts = np.concatenate([e.reshape(-1, 3), t.reshape(-1, 3)])
    if len(pts):
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        lines.append(
            "  centre range [m]: "
            + ", ".join(f"{c} {a:+.3f}..{b:+.3f}" for c, a, b in zip("xyz", lo, hi, strict=True))
        )
    if len(t) and t.shape[1] > 1:
        step = np.linalg.norm(np.diff(t[:, :, 1:], axis=1), axis=2)
        fast = float(step.max()) / dt if isinstance(dt, int | float) else float("nan")
        lines.append(f"  fastest lateral shield speed on a terminal edge: {fast:.2f} m/s")
    return lines


def _stats_row(label: str, x: np.ndarray) -> str:
    if x.size == 0:
        return f"  {label:<28} none"
    q = np.percentile(x, [0, 50, 90, 100])
    return f"  {label:<28}" + " ".join(f"{v:8.3f}" for v in q)


def _yz(yz: np.ndarray) -> str:
    y, z = np.round(yz, 6) + 0.0  # + 0.0 turns -0.0 into 0.0
    return f"(y {y:+.3f}, z {z:.3f})"


def tree_diff(a: ActionTree, b: ActionTree) -> TreeDiff:
    """Compare two trees: first what they were compiled from and with (resolved parameters,
    config text, robot files, versions, machine; a ``defect`` line when equal inputs gave
    different datasets), then the datasets: counts per depth, shield paths, goals, earliest
    arrival times.

    Goals are matched by their plane position (y, z) rounded to 1e-6 m, since goal indices differ
    between trees. See :class:`TreeDiff` for when two trees are the same.
    """
    fa, fb = tree_fingerprint(a), tree_fingerprint(b)
    sa, sb = array_checksums(a), array_checksums(b)
    differ = [name for name in sa if sa[name] != sb[name]]
    prov = provenance_diff(a.meta, b.meta)
    lines = [_headline("A", a, fa), _headline("B", b, fb), *prov.lines]
    if prov.inputs_equal and differ:
        lines.append(defect_line(prov))
    shown = ", ".join(differ[:LARGEST]) + (", ..." if len(differ) > LARGEST else "")
    count = f"{len(differ)} of {len(sa)} differ ({shown})"
    lines.append(f"datasets: {count}" if differ else "datasets: equal")
    lines += _count_lines(a, b)
    lines += _shield_diff(a, b)
    lines += _goal_lines(a, b)
    if fa == fb:
        lines.append(f"same: identical datasets and identity attributes (fingerprint {fa[:16]})")
    else:
        why = ["datasets"] if differ else []
        for key in identity_changes(a.meta, b.meta):
            name = "robot files" if key in ROBOT_KEYS else key
            why += [name] if name not in why else []
        lines.append(f"different: {_and(why)} differ")
    return TreeDiff(same=fa == fb, text="\n".join(lines))


def _and(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def _headline(label: str, t: ActionTree, fingerprint: str) -> str:
    return (
        f"{label}: {t.n_nodes} nodes, {t.n_terminals} terminal edges, max depth {t.max_depth},"
        f" created {t.meta.get('created', '?')}, fingerprint {fingerprint[:16]}"
    )


def _count_lines(a: ActionTree, b: ActionTree) -> list[str]:
    ca, cb = depth_counts(a), depth_counts(b)
    n = max(len(ca), len(cb))
    ca = np.pad(ca, ((0, n - len(ca)), (0, 0)))
    cb = np.pad(cb, ((0, n - len(cb)), (0, 0)))
    names = ("nodes", "cut", "reached", "terminals")
    out = [f"  max depth: {a.max_depth} -> {b.max_depth}"] if a.max_depth != b.max_depth else []
    for d in np.flatnonzero(np.any(ca != cb, axis=1)):
        parts = [f"{k} {x} -> {y}" for k, x, y in zip(names, ca[d], cb[d], strict=True) if x != y]
        out.append(f"  depth {d}: " + ", ".join(parts))
    return ["counts per depth: " + ("changed" if out else "equal"), *out]


def _shield_diff(a: ActionTree, b: ActionTree) -> list[str]:
    """Shield paths: equal, or what changed (spacing, samples, largest move of a sample)."""
    out = []
    da, db = a.meta.get("shield_dt"), b.meta.get("shield_dt")
    if da != db:
        out.append(f"  spacing [s]: {da} -> {db}")
    for label, x, y in (("tree edge", a.edge_shield, b.edge_shield),
                        ("terminal", a.term_shield, b.term_shield)):  # fmt: skip
        if x.shape != y.shape:
            out.append(f"  {label} samples: {x.shape} -> {y.shape}")
        elif not np.array_equal(x, y):
            d = np.max(np.linalg.norm(x - y, axis=2), axis=1)
            out.append(
                f"  {label} paths: {int(np.count_nonzero(d))} of {len(d)} differ,"
                f" largest {float(d.max()):.3g} m (row {int(np.argmax(d))})"
            )
    return ["shield paths: " + ("changed" if out else "equal"), *out]


def _goal_keys(t: ActionTree) -> dict[tuple[int, int], int]:
    keys = np.rint(t.goal_yz * GOAL_KEY_SCALE).astype(np.int64)
    return {(int(y), int(z)): i for i, (y, z) in enumerate(keys)}


def _key_yz(key: tuple[int, int]) -> str:
    return _yz(np.array(key) / GOAL_KEY_SCALE)


def _goal_lines(a: ActionTree, b: ActionTree) -> list[str]:
    ka, kb = _goal_keys(a), _goal_keys(b)
    ea, eb = earliest_arrival(a), earliest_arrival(b)
    cov_a = {k for k, i in ka.items() if np.isfinite(ea[i])}
    cov_b = {k for k, i in kb.items() if np.isfinite(eb[i])}
    lines = ["goals (matched by plane y, z to 1e-6 m):"]
    lines.append(_set_change("reachable", set(ka), set(kb)))
    lines.append(_set_change("covered", cov_a, cov_b))
    for label, keys in (("gained", cov_b - cov_a), ("lost", cov_a - cov_b)):
        if keys:
            shown = sorted(keys)[:LARGEST]
            more = ", ..." if len(keys) > LARGEST else ""
            lines.append(f"  {label}: " + ", ".join(map(_key_yz, shown)) + more)
    both = sorted(cov_a & cov_b)
    ta = np.array([ea[ka[k]] for k in both])
    tb = np.array([eb[kb[k]] for k in both])
    lines.append(f"earliest arrival time [s], {len(both)} goals covered in both:")
    if not both:
        return lines
    delta = tb - ta
    better, worse = delta < -ARRIVAL_TOL, delta > ARRIVAL_TOL
    lines.append(
        f"  mean change {delta.mean():+.4f}; improved {int(better.sum())}"
        f" (max {-delta.min() if better.any() else 0.0:.4f}), regressed {int(worse.sum())}"
        f" (max {delta.max() if worse.any() else 0.0:.4f}),"
        f" unchanged {int((~better & ~worse).sum())} (within {ARRIVAL_TOL:g} s)"
    )
    changed = better | worse
    order = [i for i in np.argsort(-np.abs(delta), kind="stable") if changed[i]][:LARGEST]
    if order:
        lines.append("  largest changes (B - A):")
    lines += [
        f"    {_key_yz(both[i])}: {ta[i]:.4f} -> {tb[i]:.4f} ({delta[i]:+.4f})" for i in order
    ]
    return lines


def colour_span(delta: np.ndarray) -> float:
    """Half-range of the B - A colour scale [s]: the largest |change|, never below
    :data:`MIN_COLOUR_SPAN` (float noise would otherwise fill the scale)."""
    return max(float(np.abs(delta).max()) if np.size(delta) else 0.0, MIN_COLOUR_SPAN)


def _set_change(label: str, a: set, b: set) -> str:
    return f"  {label}: {len(a)} -> {len(b)} (gained {len(b - a)}, lost {len(a - b)})"


def diff_png(a: ActionTree, b: ActionTree, path: str) -> None:
    """Draw earliest arrival time over the plane for A, B and B - A into a PNG file.

    The plane is drawn as ``thinkfast-compile goals`` prints it, as the thrower sees it: base y
    increasing to the right, z up. Goals
    without a terminal edge are grey crosses; B - A uses a diverging map centred on 0 (blue is
    faster in B) over the goals covered in both, the others crossed.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ea, eb = earliest_arrival(a), earliest_arrival(b)
    ka, kb = _goal_keys(a), _goal_keys(b)
    both = [k for k in ka if k in kb and np.isfinite(ea[ka[k]]) and np.isfinite(eb[kb[k]])]
    yz_both = np.array(both, dtype=float).reshape(-1, 2) / GOAL_KEY_SCALE
    delta = np.array([eb[kb[k]] - ea[ka[k]] for k in both])
    finite = np.concatenate([ea[np.isfinite(ea)], eb[np.isfinite(eb)]])
    lo, hi = (finite.min(), finite.max()) if finite.size else (0.0, 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5))
    for ax, t, e, title in ((axes[0], a, ea, "A"), (axes[1], b, eb, "B")):
        ok = np.isfinite(e)
        sc = ax.scatter(*t.goal_yz[ok].T, c=e[ok], cmap="viridis", vmin=lo, vmax=hi, marker="s")
        ax.scatter(*t.goal_yz[~ok].T, c="0.6", marker="x", label="no terminal edge")
        ax.set_title(f"{title}: earliest arrival ({int(ok.sum())}/{len(e)} goals)")
        fig.colorbar(sc, ax=ax, shrink=0.8, label="earliest arrival time [s]")
    span = colour_span(delta)
    sc = axes[2].scatter(
        *yz_both.T, c=delta, cmap="RdBu_r", vmin=-span, vmax=span, marker="s", edgecolors="0.7"
    )
    others = np.array([k for k in {*ka, *kb} if k not in set(both)], dtype=float)
    if others.size:
        axes[2].scatter(*(others / GOAL_KEY_SCALE).T, c="0.6", marker="x", label="not in both")
    axes[2].set_title(f"B - A: {len(both)} goals covered in both")
    fig.colorbar(sc, ax=axes[2], shrink=0.8, label="B - A earliest arrival [s] (blue: B faster)")
    for ax in axes:
        ax.set(xlabel=Y_LABEL, ylabel="base z [m]", aspect="equal")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
