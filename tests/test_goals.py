"""IK goal grid: every reported goal is re-checked independently; spacing is free."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.conftest import DEFAULT_CONFIG, run_cli
from thinkfast.compile.config import GoalsConfig, load_compile_config
from thinkfast.compile.goals import grid_axes, solve_goal_grid


@pytest.fixture(scope="module")
def default_grid(robot, kin):
    cfg = load_compile_config(DEFAULT_CONFIG).config
    return solve_goal_grid(robot, cfg.goals, cfg.plane.distance, kin)


def test_every_reported_goal_passes_an_independent_recheck(default_grid, robot, kin, checker):
    grid = default_grid
    assert grid.reachable.sum() >= 100
    for i in grid.goal_index:
        q = grid.q[i]
        pose = kin.shield(q)
        target = np.array([grid.plane_distance, *grid.yz[i]])
        assert np.linalg.norm(pose.centre - target) < 1e-3
        assert np.degrees(np.arccos(np.clip(pose.normal[0], -1, 1))) < 0.5
        assert np.all(q >= robot.q_lower) and np.all(q <= robot.q_upper)
        assert not checker.in_collision(q)


def test_unreachable_points_carry_a_reason_and_no_configuration(default_grid):
    grid = default_grid
    unreachable = np.flatnonzero(~grid.reachable)
    assert len(unreachable) > 0  # the top corners are beyond 1.45 m reach
    for i in unreachable:
        assert grid.reason[i] and np.all(np.isnan(grid.q[i]))
        assert grid.yz[i, 1] > 1.3  # only the top of the region is out of reach
    assert all(grid.reason[i] == "" for i in grid.goal_index)


def test_goal_nearest_home_is_home_and_neighbours_stay_continuous(default_grid, robot):
    grid = default_grid
    ny = len(grid.y)
    centre = int(np.argmin(np.linalg.norm(grid.yz - [0.0, 1.0], axis=1)))
    assert np.allclose(grid.q[centre], robot.home, atol=1e-6)
    jumps = []
    for i in grid.goal_index:  # horizontal and vertical neighbours
        for k in (i + 1, i + ny):
            if k < len(grid.yz) and grid.reachable[k] and (k != i + 1 or (i + 1) % ny):
                jumps.append(np.max(np.abs(grid.q[i, :3] - grid.q[k, :3])))
    # joints 1-3 never switch branch between 0.15 m neighbours (the elbow extends fast only near
    # the edge of reach)
    assert max(jumps) < 0.8


@pytest.mark.parametrize("spacing", [0.75, 0.3, 0.1])
def test_any_spacing_works(robot, kin, spacing):
    cfg = dataclasses.replace(GoalsConfig(), spacing=spacing)
    grid = solve_goal_grid(robot, cfg, 0.8, kin)
    y, z = grid_axes(cfg)
    assert len(grid.yz) == len(y) * len(z)
    assert np.allclose(np.diff(y), spacing) if len(y) > 1 else True
    assert grid.reachable.any()
    assert np.nanmax(grid.position_error) < 1e-6


def test_grid_axes_stay_inside_the_range_and_centre_the_remainder():
    y, z = grid_axes(GoalsConfig(y_min=-1.0, y_max=1.0, z_min=0.3, z_max=1.0, spacing=0.75))
    assert np.allclose(y, [-0.75, 0.0, 0.75])
    assert np.allclose(z, [0.65])  # one step does not fit in 0.7 m: the single point is centred


def test_goals_command_prints_table_and_summary_and_png(tmp_path):
    png = tmp_path / "goals.png"
    proc = run_cli("thinkfast-compile", "goals", str(DEFAULT_CONFIG), "--png", str(png))
    assert proc.returncode == 0, proc.stderr
    assert "reachable:" in proc.stdout and "z \\ y" in proc.stdout
    assert png.stat().st_size > 10_000
