"""Independent re-check of a compiled tree.

Every tree edge and terminal edge is recomputed with Ruckig from the stored parent state: kind,
duration and end state must match the stored ones (1e-9), time-to-come must be the parent's plus
the edge's, and terminal edges must end at their goal at rest to Ruckig's precision (1e-7: its
solver lands within about 1e-8 rad of a target). Limits and collisions are re-checked along every
primitive at a finer collision resolution (default 4x) and sampling step than the compiler used.
The stored shield paths (``/edges/shield``, ``/terminals/shield``) are sampled again from the
recomputed primitives and must agree to ``SHIELD_TOL``.
"""

from __future__ import annotations

import multiprocessing as mp
from collections import Counter
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from thinkfast.compile.config import CompileConfig
from thinkfast.compile.grow import Progress, _run
from thinkfast.compile.pathcheck import PathChecker
from thinkfast.compile.shield import edge_shield_paths
from thinkfast.errors import NoSolutionError
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import Steering, state_at
from thinkfast.tree.action_tree import EDGE_CUT, EDGE_REACHED, ActionTree

TOL = 1e-9  # recomputed vs stored: the same computation, so equal to rounding
GOAL_TOL = 1e-7  # rad, rad/s, rad/s^2: Ruckig reaches its target state to about 1e-8
SHIELD_TOL = 1e-9  # m: the stored shield samples are the same computation


class VerifyReport(NamedTuple):
    """Outcome: ``ok`` when no problem was found; ``problems`` lists the first ones found."""

    ok: bool
    problems: list[str]
    edges: int
    terminals: int
    checks: int


@dataclass(frozen=True)
class _Inputs:
    robot: Robot
    config: CompileConfig
    factor: float
    tree: ActionTree


_V: dict = {}


def _init(inputs: _Inputs) -> None:
    cfg, robot = inputs.config.tree, inputs.robot
    _V["in"] = inputs
    n = robot.n_arm  # the tree's joints, q[:n]; the wrist's: q[n:]
    _V["steer"] = Steering(robot.v_max[:n], robot.a_max[:n], robot.j_max[:n])
    _V["check"] = PathChecker(
        robot,
        cfg.collision_resolution / inputs.factor,
        cfg.position_margin,
        cfg.sample_dt / inputs.factor,
    )


def _edge(i: int) -> tuple[list[str], int]:
    inp, steer, check = _V["in"], _V["steer"], _V["check"]
    t, eps, n = inp.tree, inp.config.tree.eps, inp.robot.n_arm
    p = int(t.node_parent[i])
    goal = t.goal_q[t.subgoal_goal[t.edge_target[i]], :n]
    try:
        traj = steer.steer(t.node_state[p], goal)
    except NoSolutionError as exc:
        return [f"node {i}: {exc}"], 0
    reached = traj.duration <= eps
    t_move = traj.duration if reached else eps
    out = []
    if t.edge_kind[i] != (EDGE_REACHED if reached else EDGE_CUT):
        out.append(f"node {i}: edge kind {t.edge_kind[i]} but the primitive says reached={reached}")
    if t.edge_duration[i] != eps:
        out.append(f"node {i}: edge duration {t.edge_duration[i]} != eps {eps}")
    if np.max(np.abs(state_at(traj, t_move) - t.node_state[i])) > TOL:
        out.append(f"node {i}: state differs from the recomputed primitive")
    if t.node_ttc[i] != t.node_ttc[p] + t.edge_duration[i]:
        out.append(f"node {i}: time-to-come is not parent + duration")
    checks = 0
    if t_move > 0.0:
        res = check.check(traj, t_move, t.node_q[p, n:])
        checks = res.checks
        if not res.ok:
            out.append(f"node {i}: {res.reason} ({res.detail}) at the finer resolution")
        elif np.max(np.abs(res.wrist_end - t.node_q[i, n:])) > 1e-6:
            out.append(f"node {i}: wrist differs from the coplanar rule")
    return out, checks


def _terminal(k: int) -> tuple[list[str], int]:
    inp, steer, check = _V["in"], _V["steer"], _V["check"]
    t, n = inp.tree, inp.robot.n_arm
    node, g = int(t.term_node[k]), int(t.term_goal[k])
    try:
        traj = steer.steer(t.node_state[node], t.goal_q[g, :n])
    except NoSolutionError as exc:
        return [f"terminal {k}: {exc}"], 0
    out = []
    if abs(traj.duration - t.term_duration[k]) > TOL:
        out.append(f"terminal {k}: duration {t.term_duration[k]} != {traj.duration}")
    end = state_at(traj, traj.duration)
    if np.max(np.abs(end[:n] - t.goal_q[g, :n])) > GOAL_TOL or np.max(np.abs(end[n:])) > GOAL_TOL:
        out.append(f"terminal {k}: does not end at goal {g} at rest")
    if t.term_arrival[k] != t.node_ttc[node] + t.term_duration[k]:
        out.append(f"terminal {k}: arrival is not time-to-come + duration")
    res = check.check(traj, traj.duration, t.node_q[node, n:])
    if not res.ok:
        out.append(f"terminal {k}: {res.reason} ({res.detail}) at the finer resolution")
    return out, res.checks


def _checked(one, chunk: list) -> tuple[list, Counter]:
    """Problems and collision-check count of ``one(i)`` over a chunk of indices."""
    probs, n = [], Counter()
    for i in chunk:
        p, c = one(i)
        probs += p
        n["checks"] += c
    return probs, n


def _edges_chunk(chunk: list) -> tuple[list, Counter]:
    return _checked(_edge, chunk)


def _terminals_chunk(chunk: list) -> tuple[list, Counter]:
    return _checked(_terminal, chunk)


def verify_tree(
    tree: ActionTree,
    robot: Robot,
    config: CompileConfig,
    factor: float = 4.0,
    jobs: int = 1,
    progress: Progress | None = None,
) -> VerifyReport:
    """Recompute and re-check every edge of ``tree``.

    Args:
        tree: the loaded tree.
        robot: the robot it was compiled for.
        config: its compile configuration (from the file's resolved ``parameters``).
        factor: how much finer than at compile time collisions and limits are re-checked.
        jobs: worker processes.
        progress: called with (phase, done, total).
    """
    problems = []
    if robot.urdf_sha256 != tree.meta.get("urdf_sha256"):
        problems.append(f"{robot.urdf_path}: URDF differs from the one the tree was compiled for")
    if robot.toml_sha256 != tree.meta.get("robot_toml_sha256"):
        problems.append(f"{robot.toml_path}: robot.toml differs from the compile-time one")
    n = robot.n_arm  # the tree's joints, q[:n]
    if tree.node_ttc[0] != 0.0 or np.any(tree.node_state[0, n:] != 0.0):
        problems.append("root is not at rest at time 0")
    if np.max(np.abs(tree.node_state[0, :n] - robot.home[:n])) > TOL:
        problems.append("root is not at home")
    inputs = _Inputs(robot, config, factor, tree)
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    pool = ctx.Pool(jobs, _init, (inputs,)) if jobs > 1 else None
    if pool is None:
        _init(inputs)
    try:
        edge_items = list(range(1, tree.n_nodes))
        p1, c1 = _run(_edges_chunk, edge_items, pool, progress, "edges", 1)
        term_items = list(range(tree.n_terminals))
        p2, c2 = _run(_terminals_chunk, term_items, pool, progress, "terminals", 1)
    finally:
        if pool is not None:
            pool.close()
            pool.join()
    problems += p1 + p2
    if progress:
        progress("shield paths", 0, 1)
    problems += shield_problems(tree, robot, config)
    if progress:
        progress("shield paths", 1, 1)
    return VerifyReport(
        not problems, problems, len(edge_items), len(term_items), c1["checks"] + c2["checks"]
    )


def shield_problems(tree: ActionTree, robot: Robot, config: CompileConfig) -> list[str]:
    """Disagreements between the stored shield paths and ones sampled again (first few)."""
    dt = float(tree.meta.get("shield_dt", config.tree.shield_dt))
    try:
        edge, term = edge_shield_paths(
            robot, tree.node_parent, tree.node_state, tree.edge_target, tree.term_node,
            tree.term_goal, tree.term_duration, tree.goal_q, tree.subgoal_goal,
            config.tree.eps, dt,
        )  # fmt: skip
    except (NoSolutionError, ValueError) as exc:
        return [f"shield paths: cannot sample again ({exc})"]
    out = []
    for label, stored, again in (
        ("edge", tree.edge_shield, edge),
        ("terminal", tree.term_shield, term),
    ):
        if stored.shape != again.shape:
            out.append(f"{label} shield paths: shape {stored.shape}, expected {again.shape}")
            continue
        err = np.max(np.abs(stored - again), axis=(1, 2)) if len(again) else np.zeros(0)
        bad = np.flatnonzero(err > SHIELD_TOL)
        out += [
            f"{label} {i}: shield path differs by {err[i]:.3g} m from the recomputed primitive"
            for i in bad[:10]
        ]
        if len(bad) > 10:
            out.append(f"{label} shield paths: {len(bad) - 10} more differ")
    return out
