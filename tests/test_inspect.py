"""info / diff / diff figure: every kind of change between two trees is reported, and only those."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from tests.treegen import random_tree, with_config, with_terminals
from thinkfast.compile.inspect import (
    depth_counts,
    diff_png,
    earliest_arrival,
    tree_diff,
    tree_info,
)
from thinkfast.compile.provenance_text import resolved_parameters
from thinkfast.tree.action_tree import EDGE_CUT, ActionTree
from thinkfast.tree.file import load_tree, save_tree


@pytest.fixture(scope="module")
def tree() -> ActionTree:
    return random_tree(7, max_depth=3)


def yz_text(t: ActionTree, g: int) -> str:
    y, z = np.round(t.goal_yz[g], 6) + 0.0
    return f"(y {y:+.3f}, z {z:.3f})"


def drop_goal(t: ActionTree, g: int) -> ActionTree:
    keep = t.term_goal != g
    return with_terminals(t, t.term_node[keep], t.term_goal[keep], t.term_duration[keep])


def test_depth_counts_and_earliest_arrival_match_brute_force(tree):
    counts = depth_counts(tree)
    for d in range(tree.max_depth + 1):
        at = [i for i in range(tree.n_nodes) if tree.node_depth[i] == d]
        cut = sum(1 for i in at if i > 0 and tree.edge_kind[i] == EDGE_CUT)
        terms = sum(1 for n in tree.term_node if tree.node_depth[n] == d)
        reached = len(at) - cut if d > 0 else 0
        assert counts[d].tolist() == [len(at), cut, reached, terms]
    ea = earliest_arrival(tree)
    for g in range(len(tree.goal_yz)):
        arrivals = tree.term_arrival[tree.term_goal == g]
        assert ea[g] == (arrivals.min() if arrivals.size else np.inf)


def test_info_shows_counts_per_depth_coverage_arrival_stats_parameters_and_provenance(tree):
    text = tree_info(tree)
    counts = depth_counts(tree)
    for d, (nodes, cut, reached, terms) in enumerate(counts):
        edges = r"-\s+-" if d == 0 else rf"{cut}\s+{reached}"
        assert re.search(rf"^\s+{d}\s+{nodes}\s+{edges}\s+{terms}$", text, re.M), d
    covered = int(np.isfinite(earliest_arrival(tree)).sum())
    g, m = len(tree.goal_yz), len(tree.grid_yz)
    assert f"goals: {covered} covered by a terminal edge / {g} reachable / {m} grid points" in text
    p90 = np.percentile(tree.term_arrival, 90)
    assert re.search(rf"terminal edges \({tree.n_terminals}\)\s+[\d.]+\s+[\d.]+\s+{p90:.3f}", text)
    assert f"earliest per goal ({covered})" in text
    assert "tree.max_depth = 3" in text and "tree.eps = 0.1" in text
    assert "tree.connect_min = 2" in text  # a default the config text does not name
    assert tree.meta["config_sha256"][:12] in text and "ruckig_version = 0.19.4" in text
    assert "created = 2025-01-01T00:00:00Z" in text
    assert "machine:\n  cpu = 'Test CPU 9000'" in text and "blas.architecture = 'Haswell'" in text
    assert "discards:" in text and "collision = 5" in text
    assert "config_text" not in text


def test_info_shows_discard_counts_given_as_dicts_or_json_strings(tree):
    meta = dict(tree.meta, tree_discards='{"joint_limit": 4}', terminal_discards={})
    text = tree_info(dataclasses.replace(tree, meta=meta))
    assert "tree_discards:\n  joint_limit = 4\n" in text
    assert "terminal_discards: none" in text


def test_info_survives_a_tree_without_terminals_or_config():
    t = random_tree(1, terminals_per_leaf=0)
    text = tree_info(dataclasses.replace(t, meta={}))
    assert "goals: 0 covered" in text and "none recorded" in text and "none" in text


def test_diff_of_a_tree_with_itself_and_its_reloaded_copy_is_same(tree, tmp_path):
    assert tree_diff(tree, tree).same
    meta = {k: v for k, v in tree.meta.items() if k != "created"}
    save_tree(dataclasses.replace(tree, meta=meta), tmp_path / "t.h5")
    result = tree_diff(tree, load_tree(tmp_path / "t.h5"))
    assert result.same, result.text
    assert "  parameters: equal (resolved" in result.text and "datasets: equal" in result.text
    assert "counts per depth: equal" in result.text and "defect" not in result.text
    assert result.text.splitlines()[-1].startswith("same:")


def test_a_changed_parameter_is_reported_even_with_identical_arrays(tree):
    result = tree_diff(tree, with_config(tree, "max_depth = 3", "max_depth = 4"))
    assert not result.same
    assert "  parameters: 1 of 23 differ (resolved, defaults filled in):\n" in result.text
    assert "\n    tree.max_depth: 3 -> 4\n" in result.text
    assert result.text.splitlines()[-1] == "different: parameters differ"


def test_a_default_left_out_of_or_written_into_the_text_is_no_change(tree):
    """The resolved parameters are compared, not the TOML text: a default the text does not
    write is the same value, and a key that differs shows both resolved values."""
    left_out = with_config(tree, "eps = 0.1\n", "")
    written = with_config(tree, "connect_radius = 0.3\n", "connect_radius = 0.3\nconnect_min = 2\n")
    for b in (left_out, written):
        result = tree_diff(tree, b)
        assert result.same, result.text
        assert "  parameters: equal (resolved" in result.text
        assert "config sha256: " in result.text and "(text only: comments, layout" in result.text
    text = tree_diff(left_out, with_config(tree, "eps = 0.1\n", "eps = 0.12\n")).text
    assert "  parameters: 1 of 23 differ" in text and "    tree.eps: 0.1 -> 0.12" in text
    assert "absent" not in text and "not recorded" not in text


def test_comments_and_formatting_in_the_config_are_not_changes(tree):
    b = with_config(tree, "max_depth = 3", "max_depth   =   3   # deeper costs time")
    assert tree_diff(tree, b).same


def test_a_removed_depth_level_is_reported_per_depth():
    a, b = random_tree(3, max_depth=3), random_tree(3, max_depth=2)
    result = tree_diff(a, b)
    assert not result.same
    assert "max depth: 3 -> 2" in result.text
    nodes3 = int(depth_counts(a)[3, 0])
    assert re.search(rf"^  depth 3: nodes {nodes3} -> 0, .*terminals \d+ -> 0$", result.text, re.M)


def test_a_lost_goal_is_reported_with_its_position_and_gained_the_other_way(tree):
    g = int(tree.term_goal[0])
    b = drop_goal(tree, g)
    covered = int(np.isfinite(earliest_arrival(tree)).sum())
    text = tree_diff(tree, b).text
    assert f"covered: {covered} -> {covered - 1} (gained 0, lost 1)" in text
    assert f"  lost: {yz_text(tree, g)}" in text
    assert f"  gained: {yz_text(tree, g)}" in tree_diff(b, tree).text


def test_arrival_time_changes_are_summarised_and_the_largest_listed(tree):
    g_slow, g_fast = (int(x) for x in np.unique(tree.term_goal)[:2])
    duration = tree.term_duration.copy()
    duration[tree.term_goal == g_slow] += 0.05
    duration[tree.term_goal == g_fast] -= 0.02
    b = with_terminals(tree, tree.term_node, tree.term_goal, duration)
    result = tree_diff(tree, b)
    assert not result.same
    assert "improved 1 (max 0.0200), regressed 1 (max 0.0500)" in result.text
    ea = earliest_arrival(tree)
    assert (
        f"    {yz_text(tree, g_slow)}: {ea[g_slow]:.4f} -> {ea[g_slow] + 0.05:.4f} (+0.0500)"
        in (result.text)
    )
    lines = result.text.splitlines()
    first = lines.index("  largest changes (B - A):")
    assert "(+0.0500)" in lines[first + 1] and "(-0.0200)" in lines[first + 2]


def test_goals_are_matched_by_position_not_by_index(tree):
    rng = np.random.default_rng(0)
    g = len(tree.goal_yz)
    perm = rng.permutation(g)  # new goal i is old goal perm[i]
    new_index = np.argsort(perm)
    b = dataclasses.replace(
        tree,
        goal_q=tree.goal_q[perm],
        goal_yz=tree.goal_yz[perm],
        goal_grid_index=tree.goal_grid_index[perm],
        subgoal_goal=new_index[tree.subgoal_goal].astype(np.int32),
    )
    b = with_terminals(b, tree.term_node, new_index[tree.term_goal], tree.term_duration)
    result = tree_diff(tree, b)
    assert not result.same  # the arrays differ ...
    assert f"reachable: {g} -> {g} (gained 0, lost 0)" in result.text
    assert "(gained 0, lost 0)" in result.text.split("covered:")[1]
    assert "regressed 0" in result.text and "improved 0" in result.text  # ... the goals do not


def test_robot_hash_changes_are_reported_and_make_another_tree(tree):
    meta = dict(tree.meta, urdf_sha256="f" * 64)
    result = tree_diff(tree, dataclasses.replace(tree, meta=meta))
    assert "  robot files: differ\n" in result.text
    assert f"    urdf_sha256: {tree.meta['urdf_sha256']!r} -> {'f' * 64!r}" in result.text
    assert not result.same  # the robot files are part of the identity: see TreeDiff.same
    assert result.text.splitlines()[-1] == "different: robot files differ"
    assert "defect" not in result.text


def test_equal_inputs_with_different_datasets_are_a_defect_naming_machine_and_versions(tree):
    """Same parameters and robot files, other arrays: one ``defect`` line naming the machine
    and version fields that differ."""
    machine = {**tree.meta["machine"], "cpu": "Other CPU", "blas": {"architecture": "Zen"}}
    meta = {**tree.meta, "numpy_version": "1.26.4", "machine": machine}
    ttc = tree.node_ttc.copy()
    ttc[1] += 1e-12
    b = dataclasses.replace(tree, node_ttc=ttc, meta=meta)
    result = tree_diff(tree, b)
    assert not result.same
    defect = [line for line in result.text.splitlines() if line.startswith("defect:")]
    assert defect == [
        "defect: equal inputs gave different trees (machine differs: cpu 'Test CPU 9000' ->"
        " 'Other CPU', blas.name 'scipy-openblas' -> (not recorded), blas.version '0.3.31' ->"
        " (not recorded), blas.architecture 'Haswell' -> 'Zen'; versions differ: numpy"
        " '2.4.6' -> '1.26.4')"
    ]
    assert "datasets: 1 of 24 differ (node_ttc)" in result.text
    assert result.text.splitlines()[-1] == "different: datasets differ"
    same_machine = tree_diff(tree, dataclasses.replace(tree, node_ttc=ttc)).text
    assert "(same versions and machine: the compile is not deterministic)" in same_machine


def test_versions_and_machine_alone_do_not_make_another_tree(tree):
    meta = {**tree.meta, "numpy_version": "1.26.4", "machine": {"cpu": "Other CPU"}}
    result = tree_diff(tree, dataclasses.replace(tree, meta=meta))
    assert result.same, result.text
    assert "  versions: differ: numpy '2.4.6' -> '1.26.4'" in result.text
    assert "  machine: differ: cpu 'Test CPU 9000' -> 'Other CPU'," in result.text
    assert "defect" not in result.text


def test_resolved_parameters_fill_in_defaults_and_tolerate_bad_values(tree):
    params = resolved_parameters(tree.meta)
    assert params["tree.max_depth"] == 3 and params["plane.distance"] == 0.8
    assert params["tree.connect_min"] == 2 and params["goals.continuity"] == 1.0  # defaults
    assert resolved_parameters({"parameters": "not json"}) is None
    assert resolved_parameters({"parameters": "[1, 2]"}) is None
    assert resolved_parameters({}) is None


def test_diff_png_is_written(tree, tmp_path):
    b = drop_goal(tree, int(tree.term_goal[0]))
    diff_png(tree, b, str(tmp_path / "d.png"))
    assert (tmp_path / "d.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    empty = random_tree(1, terminals_per_leaf=0)
    diff_png(empty, empty, str(tmp_path / "e.png"))
    assert (tmp_path / "e.png").stat().st_size > 1000
