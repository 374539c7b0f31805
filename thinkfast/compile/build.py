"""Compile a configuration into an :class:`ActionTree`: goal grid, growth, provenance."""

from __future__ import annotations

import datetime as dt
import json
import time

import numpy as np

from thinkfast.compile.config import LoadedConfig
from thinkfast.compile.goals import require_reachable, solve_goal_grid
from thinkfast.compile.grow import GrowInputs, Progress, grow, subgoals
from thinkfast.compile.home import check_home, placed_robot
from thinkfast.compile.shield import pad_terminals, sample_spacing
from thinkfast.machine import library_versions, machine_info
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.model import Robot
from thinkfast.tree.action_tree import ActionTree


def versions() -> dict[str, str]:
    """Versions of Python and the libraries that shape a tree, as meta keys ``<name>_version``
    (:func:`thinkfast.machine.library_versions`)."""
    return {f"{k}_version": v for k, v in library_versions().items()}


def shield_on_plane(robot: Robot):
    """Function mapping configurations (N, 6) [rad] to shield centres (y, z) [m] (N, 2)."""
    fk = BatchFK(robot)

    def plane_yz(q: np.ndarray) -> np.ndarray:
        return fk.link_poses(q)[robot.shield_link][:, 1:3, 3]

    return plane_yz


def compile_tree(
    loaded: LoadedConfig, jobs: int = 1, progress: Progress | None = None
) -> ActionTree:
    """Compile the action tree described by ``loaded``.

    Args:
        loaded: validated configuration with its provenance.
        jobs: worker processes.
        progress: called with (phase, done, total).
    """
    start = time.perf_counter()
    cfg = loaded.config
    robot = placed_robot(loaded)  # placed in the plane's frame
    grid = solve_goal_grid(robot, cfg.goals, cfg.plane.distance)
    require_reachable(grid, str(loaded.path))
    check_home(robot, cfg, str(loaded.path))  # robot.toml's home on this plane (a solved one is)
    reach = grid.goal_index
    goal_q = np.array(grid.q[reach])
    goal_yz = np.array(grid.yz[reach])
    plane_yz = shield_on_plane(robot)
    sub = subgoals(grid, cfg.goals, cfg.tree.subgoal_spacing, plane_yz(robot.home[None])[0])
    inputs = GrowInputs(robot, cfg.tree, goal_q, sub)
    g = grow(inputs, plane_yz, goal_yz, jobs=jobs, progress=progress)

    n = len(g["parent"])
    child_count = np.bincount(g["parent"][1:], minlength=n).astype(np.int64)
    child_start = 1 + np.cumsum(child_count) - child_count  # BFS: children follow in parent order
    terms = g["terminals"]
    term_node = np.array([t[0] for t in terms], np.int32)
    term_goal = np.array([t[1] for t in terms], np.int32)
    term_duration = np.array([t[2] for t in terms], np.float64)
    term_count = np.bincount(term_node, minlength=n).astype(np.int64)
    term_start = np.r_[0, np.cumsum(term_count)[:-1]].astype(np.int64)
    node_q = np.column_stack([g["state"][:, :3], g["wrist"]])
    shield_dt = sample_spacing(cfg.tree.eps, cfg.tree.shield_dt)
    longest = float(np.max(term_duration)) if len(term_duration) else 0.0
    term_shield = pad_terminals(g["terminal_shield"], longest, shield_dt)  # sampled by grow
    meta = {
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        **versions(),
        "machine": machine_info(),
        "config_path": str(loaded.path.resolve()),
        "config_text": loaded.text,
        "config_sha256": loaded.sha256,
        "urdf_sha256": robot.urdf_sha256,
        "robot_toml_sha256": robot.toml_sha256,
        "robot_name": robot.name,
        "parameters": json.dumps(loaded.parameters(robot)),
        "plane_distance": cfg.plane.distance,
        "shield_radius": robot.shield_radius,
        "shield_dt": shield_dt,
        "tree_discards": json.dumps(g["tree_discards"], sort_keys=True),
        "terminal_discards": json.dumps(g["terminal_discards"], sort_keys=True),
        "jobs": jobs,
        "compile_seconds": round(time.perf_counter() - start, 3),
    }
    return ActionTree(
        node_parent=g["parent"],
        node_depth=g["depth"],
        node_ttc=g["ttc"],
        node_state=g["state"],
        node_q=node_q,
        edge_kind=g["kind"],
        edge_duration=g["duration"],
        edge_target=g["target"],
        child_start=child_start,
        child_count=child_count,
        term_start=term_start,
        term_count=term_count,
        term_node=term_node,
        term_goal=term_goal,
        term_duration=term_duration,
        term_arrival=g["ttc"][term_node] + term_duration,
        goal_q=goal_q,
        goal_yz=goal_yz,
        goal_grid_index=np.asarray(reach, np.int32),
        subgoal_goal=sub,
        grid_yz=np.array(grid.yz),
        grid_reachable=np.array(grid.reachable),
        edge_shield=g["edge_shield"],
        term_shield=term_shield,
        meta=meta,
    ).freeze()
