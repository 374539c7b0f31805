"""Smaller faults of issue 14: an unreachable plane, float noise in diff, plot axes and bars."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import ROBOT_TOML, assert_one_line_error, run_cli
from tests.treegen import random_tree, with_terminals
from thinkfast.compile.inspect import MIN_COLOUR_SPAN, colour_span, earliest_arrival, tree_diff
from thinkfast.sim.bench import BINS, bin_errors, summarize, summary_figure
from thinkfast.sim.lockstep import Outcome
from thinkfast.sim.stats import wilson

FAR_PLANE = f"""robot = "{ROBOT_TOML}"
[plane]
distance = 3.0
[goals]
y_min = -0.3
y_max = 0.3
z_min = 0.8
z_max = 1.2
spacing = 0.2
"""


@pytest.mark.parametrize("command", ["goals", "tree"])
def test_a_plane_with_no_reachable_goal_is_one_clear_error(tmp_path, command):
    cfg = tmp_path / "far.toml"
    cfg.write_text(FAR_PLANE)
    extra = ["-o", str(tmp_path / "t.h5"), "--jobs", "1"] if command == "tree" else []
    proc = run_cli("thinkfast-compile", command, str(cfg), *extra)
    assert proc.returncode == 1
    assert_one_line_error(
        proc, str(cfg), "plane.distance", "no goal is reachable", "12 out of reach", "goals."
    )
    assert "internal error" not in proc.stderr
    if command == "goals":  # the table still shows why, before the error
        assert "reachable: 0 / 12 goals" in proc.stdout
    assert not (tmp_path / "t.h5").exists()


@pytest.fixture(scope="module")
def tree():
    return random_tree(7, max_depth=3)


def test_diff_counts_float_noise_as_unchanged(tree):
    rng = np.random.default_rng(3)
    noise = rng.uniform(-1e-10, 1e-10, size=len(tree.term_duration))
    b = with_terminals(tree, tree.term_node, tree.term_goal, tree.term_duration + noise)
    text = tree_diff(tree, b).text
    covered = int(np.isfinite(earliest_arrival(tree)).sum())
    assert "improved 0 (max 0.0000), regressed 0 (max 0.0000)" in text
    assert f"unchanged {covered} (within 1e-06 s)" in text
    assert "largest changes" not in text


def test_diff_still_counts_a_real_change_among_the_noise(tree):
    g = int(np.unique(tree.term_goal)[0])
    duration = tree.term_duration + 1e-10
    duration[tree.term_goal == g] += 0.001
    b = with_terminals(tree, tree.term_node, tree.term_goal, duration)
    text = tree_diff(tree, b).text
    assert "improved 0 (max 0.0000), regressed 1 (max 0.0010)" in text
    assert text.count("(+0.0010)") == 1


def test_diff_colour_scale_never_shrinks_to_noise():
    assert colour_span(np.array([1e-10, -3e-10])) == MIN_COLOUR_SPAN
    assert colour_span(np.array([])) == MIN_COLOUR_SPAN
    assert colour_span(np.array([0.02, -0.05])) == 0.05


def test_goal_figure_has_y_increasing_to_the_right_like_the_table(robot, kin):
    from thinkfast.compile.config import GoalsConfig
    from thinkfast.compile.goals import solve_goal_grid
    from thinkfast.compile.report import goal_figure, goal_table

    grid = solve_goal_grid(robot, GoalsConfig(-0.3, 0.3, 0.9, 1.1, 0.3), 0.8, kin)
    table = goal_table(grid, robot, kin.shield(robot.home).centre)
    header = next(line for line in table.splitlines() if line.startswith("  z \\ y"))
    assert header.split()[3:] == ["-0.30", "+0.00", "+0.30"]  # table: -y left, +y right
    fig = goal_figure(grid, robot)
    ax = fig.axes[0]
    lo, hi = ax.get_xlim()
    assert lo < hi and not ax.xaxis_inverted()  # figure: the same
    assert lo < -0.3 < 0.3 < hi


def _outcomes(n: int, seed: int) -> list[Outcome]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        flight = rng.uniform(BINS[0], BINS[-1])
        for p, rate in (("tree", 0.7), ("naive", 0.6)):
            blocked = bool(rng.random() < rate)
            why = "blocked" if blocked else "late"
            out.append(Outcome(f"t{i}", p, blocked, why, 0.0, flight, 0.0, 1.0, 3, True, 0.05))
    return out


def test_bench_figure_shows_throws_per_bin_intervals_and_a_legend_below_the_bars():
    s = summarize(_outcomes(120, 4), ["tree", "naive"])
    bins = s["planners"]["tree"]["by_flight_time"]
    err = bin_errors(bins)
    for i, x in enumerate(bins):
        lo, hi = wilson(x["blocked"], x["throws"])
        assert err[:, i] == pytest.approx([x["rate"] - lo, hi - x["rate"]])
    assert (err > 0).all()
    fig = summary_figure(s)
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == [
        f"{x['flight_s'][0]:.1f}-{x['flight_s'][1]:.1f}\nn={x['throws']}" for x in bins
    ]
    assert sum(x["throws"] for x in bins) == 120
    bars = [c for c in ax.containers if type(c).__name__ == "BarContainer"]
    assert len(bars) == 2 and all(c.errorbar is not None for c in bars)
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    axes_box = ax.get_window_extent()
    assert legend.y1 < axes_box.y0  # below the panel, over no bar
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert texts[0].startswith("tree (") and "[" in texts[0]


def test_bench_figure_with_an_empty_bin_draws(tmp_path):
    from thinkfast.sim.bench import plot_summary

    outs = [o for o in _outcomes(40, 5) if o.flight_time < 0.6]
    s = summarize(outs, ["tree", "naive"])
    assert s["planners"]["tree"]["by_flight_time"][-1]["throws"] == 0
    assert bin_errors(s["planners"]["tree"]["by_flight_time"])[:, -1].tolist() == [0.0, 0.0]
    plot_summary(s, str(tmp_path / "b.png"))
    assert (tmp_path / "b.png").stat().st_size > 10_000
