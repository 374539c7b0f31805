"""Action tree growth (Algorithm 1 of the paper) on joints 1-3.

From the root (home at rest), every node steers with Ruckig towards every sub-goal (to rest, minimum
time, jerk limited, from the node's non-zero state); the primitive is cut at ``eps`` and the state
at the cut is the child (``EDGE_CUT``). A primitive that reaches its sub-goal sooner holds there at
rest until ``eps`` (``EDGE_REACHED``; towards the sub-goal a node rests at, this is "wait"), so
every tree edge lasts ``eps`` and a node at depth d has time-to-come d * eps. Breadth first to
``max_depth``.

Terminal edges are full primitives ending at rest at a goal. Nodes at ``max_depth`` connect to
every goal within ``connect_radius`` of their shield centre on the plane, and every goal also to
its ``connect_min`` nearest leaves, so no reachable goal is left without a terminal edge. With
``internal_terminals`` shallower nodes connect within ``connect_radius`` too, and with
``root_connects_all`` home connects to every goal: the runtime may then commit to a direct move as
soon as the belief makes it the best branch.

Every primitive is checked by :class:`PathChecker`; what fails is dropped and counted by reason.
Work is split by parent (or node) into chunks that run in worker processes and are merged in order,
so any number of jobs gives identical arrays.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from thinkfast.compile.config import TreeConfig
from thinkfast.compile.goals import GoalGrid, microns
from thinkfast.compile.pathcheck import PathChecker
from thinkfast.compile.shield import (
    centres_at,
    sample_spacing,
    steps_per_edge,
    terminal_centres,
)
from thinkfast.errors import NoSolutionError
from thinkfast.robot.batch_traj import TrajectoryTable
from thinkfast.robot.model import Robot
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.robot.steering import Steering, state_at
from thinkfast.tree.action_tree import EDGE_CUT, EDGE_REACHED

CHUNK = 8  # parents (or leaves) per work item
TAIL = 16  # the last items of a level go one per work item: the workers finish together
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class GrowInputs:
    """What a worker needs (picklable)."""

    robot: Robot
    tree: TreeConfig
    goal_q: np.ndarray  # (G, n_joints) [rad]
    subgoal_goal: np.ndarray  # (K,) indices into goal_q


_W: dict[str, Any] = {}  # per-process worker state


def _init_worker(inputs: GrowInputs) -> None:
    robot, cfg = inputs.robot, inputs.tree
    _W["inputs"] = inputs
    n = robot.n_arm  # the tree's joints, q[:n]
    _W["steer"] = Steering(robot.v_max[:n], robot.a_max[:n], robot.j_max[:n])
    _W["check"] = PathChecker(robot, cfg.collision_resolution, cfg.position_margin, cfg.sample_dt)
    _W["sampler"] = ShieldSampler(robot)
    dt = sample_spacing(cfg.eps, cfg.shield_dt)
    _W["shield_dt"] = dt
    _W["edge_times"] = np.minimum(np.arange(steps_per_edge(cfg.eps, dt) + 1) * dt, cfg.eps)


def _expand(chunk: list[tuple[int, np.ndarray, np.ndarray]]) -> tuple[list, Counter]:
    """Children of each (node, state (3 n_arm,), wrist (n_joints - n_arm,)) in ``chunk``."""
    inputs, steer = _W["inputs"], _W["steer"]
    eps, n = inputs.tree.eps, inputs.robot.n_arm
    why, moves = Counter(), []
    for node, state, wrist in chunk:
        for k, g in enumerate(inputs.subgoal_goal):
            try:
                traj = steer.steer(state, inputs.goal_q[g, :n])
            except NoSolutionError:
                why["steering_failed"] += 1
                continue
            reached = traj.duration <= eps
            t_move = traj.duration if reached else eps  # then at rest until eps
            moves.append((node, wrist, k, traj, reached, t_move))
    todo = [m for m in moves if m[5] > 0.0]
    table = TrajectoryTable([m[3] for m in todo]) if todo else None
    checked = iter(_check(todo, table))
    out, rows, still = [], [], []  # kept edges; their rows in ``table``, or in ``still``
    for node, wrist, k, traj, reached, t_move in moves:
        if t_move > 0.0:
            res, row = next(checked)
            if not res.ok:
                why[res.reason] += 1
                continue
            wrist_end = res.wrist_end
            rows.append((False, row))
        else:
            wrist_end = wrist.copy()
            rows.append((True, len(still)))
            still.append(traj)
        kind = EDGE_REACHED if reached else EDGE_CUT
        out.append((node, kind, eps, k, state_at(traj, t_move), wrist_end))
    return _with_shield(out, rows, table, still), why


def _with_shield(out: list, rows: list, table, still: list) -> list:
    """Each kept edge of ``out`` with its shield centres along the edge (S, 3) appended, as
    :func:`thinkfast.compile.shield.edge_shield_paths` samples them."""
    sampler, times = _W["sampler"], _W["edge_times"]
    moving = [r for s, r in rows if not s]
    held = TrajectoryTable(still) if still else None
    paths = {
        False: iter(centres_at(sampler, table, moving, times)),
        True: iter(centres_at(sampler, held, np.arange(len(still)), times)),
    }
    return [(*edge, next(paths[s])) for edge, (s, _) in zip(out, rows, strict=True)]


def _check(moves: list, table) -> list:
    """(PathResult, row in ``table``) of ``moves`` = [(node, wrist, k, traj, reached, span),
    ...] in one batch (``table`` their trajectories')."""
    if not moves:
        return []
    wrists = np.array([m[1] for m in moves])
    res = _W["check"].check_many([m[3] for m in moves], [m[5] for m in moves], wrists, table)
    return list(zip(res, range(len(moves)), strict=True))


def _connect(chunk: list[tuple[int, np.ndarray, np.ndarray, list[int]]]) -> tuple[list, Counter]:
    """Terminal edges of each (leaf, state, wrist, goals) in ``chunk``: (leaf, goal, duration,
    shield centres (n, 3) every shield_dt from 0 to one sample past the end)."""
    inputs, steer = _W["inputs"], _W["steer"]
    why, moves, n = Counter(), [], inputs.robot.n_arm
    for leaf, state, wrist, goals in chunk:
        for g in goals:
            try:
                traj = steer.steer(state, inputs.goal_q[g, :n])
            except NoSolutionError:
                why["steering_failed"] += 1
                continue
            moves.append((leaf, wrist, g, traj, False, traj.duration))
    table = TrajectoryTable([m[3] for m in moves]) if moves else None
    out, rows = [], []
    for (leaf, _, g, traj, _, _), (res, row) in zip(moves, _check(moves, table), strict=True):
        if not res.ok:
            why[res.reason] += 1
            continue
        out.append((leaf, g, traj.duration))
        rows.append(row)
    paths = terminal_centres(_W["sampler"], table, rows, _W["shield_dt"]) if rows else []
    return [(*t, c) for t, c in zip(out, paths, strict=True)], why


def subgoals(grid: GoalGrid, goals_cfg, spacing: float, centre_yz: np.ndarray) -> np.ndarray:
    """Sub-goal indices into the reachable goals.

    A coarse grid of step ``spacing`` through ``centre_yz`` (home's shield position on the plane,
    so that "stay" is always one of the choices) over the goal region, each point snapped to the
    nearest reachable goal; duplicates dropped; row-major from the lowest z.
    """

    def axis(c: float, lo: float, hi: float) -> np.ndarray:
        k = np.arange(np.ceil((lo - c) / spacing - 1e-9), np.floor((hi - c) / spacing + 1e-9) + 1)
        return c + spacing * k

    ys = axis(centre_yz[0], goals_cfg.y_min, goals_cfg.y_max)
    zs = axis(centre_yz[1], goals_cfg.z_min, goals_cfg.z_max)
    yz = grid.yz[grid.goal_index]
    out: list[int] = []
    for z in zs:
        for y in ys:
            k = int(np.argmin(microns(np.linalg.norm(yz - [y, z], axis=1))))
            if k not in out:
                out.append(k)
    return np.array(out, dtype=np.int32)


def _run(fn, items: list, pool, progress: Progress | None, phase: str, per_item: int):
    head = max(len(items) - TAIL, 0)
    chunks = [items[i : min(i + CHUNK, head)] for i in range(0, head, CHUNK)]
    chunks += [[it] for it in items[head:]]
    results, why, done = [], Counter(), 0
    total = len(items) * per_item if per_item else sum(len(it[3]) for it in items)
    mapper: Iterable = pool.imap(fn, chunks) if pool is not None else map(fn, chunks)
    for chunk, (res, w) in zip(chunks, mapper, strict=True):
        results.extend(res)
        why.update(w)
        done += sum(len(c[3]) for c in chunk) if not per_item else len(chunk) * per_item
        if progress:
            progress(phase, done, total)
    return results, why


def grow(
    inputs: GrowInputs,
    leaf_plane_yz: Callable[[np.ndarray], np.ndarray],
    goal_yz: np.ndarray,
    jobs: int = 1,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Grow the tree; returns node, edge and terminal arrays (with the shield centres along
    every edge, as :func:`thinkfast.compile.shield.edge_shield_paths` samples them) plus
    discard counts.

    Args:
        inputs: robot, tree parameters, goals and sub-goals.
        leaf_plane_yz: maps configurations (L, n_joints) [rad] to shield centres on the plane
            (L, 2).
        goal_yz: goal positions on the plane (G, 2) [m].
        jobs: worker processes (1: in this process).
        progress: called with (phase, done, total).
    """
    robot, cfg = inputs.robot, inputs.tree
    n = robot.n_arm  # the tree's joints (node states: p, v, a of q[:n]); the wrist's: q[n:]
    root_state = np.r_[robot.home[:n], np.zeros(2 * n)]
    parent, depth, kind = [-1], [0], [EDGE_REACHED]
    duration, target, ttc = [0.0], [-1], [0.0]
    state, wrist = [root_state], [robot.home[n:].copy()]
    k_edge = steps_per_edge(cfg.eps, sample_spacing(cfg.eps, cfg.shield_dt))
    root_q = np.broadcast_to(root_state[:n], (1, k_edge + 1, n))
    shield = [ShieldSampler(robot).centres(root_q)[0]]  # the root's stub stays at home
    tree_why, term_why = Counter(), Counter()
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    pool = ctx.Pool(jobs, _init_worker, (inputs,)) if jobs > 1 else None
    if pool is None:
        _init_worker(inputs)
    try:
        level = [0]
        for d in range(1, cfg.max_depth + 1):
            items = [(i, state[i], wrist[i]) for i in level]
            children, why = _run(
                _expand, items, pool, progress, f"depth {d}", len(inputs.subgoal_goal)
            )
            tree_why.update(why)
            level = []
            for node, k_kind, t_end, k, s, w, c in children:
                level.append(len(parent))
                parent.append(node)
                depth.append(d)
                kind.append(k_kind)
                duration.append(t_end)
                target.append(k)
                ttc.append(ttc[node] + t_end)
                state.append(s)
                wrist.append(w)
                shield.append(c)
        goals_of = _connect_plan(inputs, depth, state, wrist, leaf_plane_yz, goal_yz)
        items = [(i, state[i], wrist[i], gl) for i, gl in goals_of]
        terms, term_why = _run(_connect, items, pool, progress, "terminals", 0)
    finally:
        if pool is not None:
            pool.close()
            pool.join()
    return dict(
        parent=np.array(parent, np.int32),
        depth=np.array(depth, np.int32),
        kind=np.array(kind, np.uint8),
        duration=np.array(duration, np.float64),
        target=np.array(target, np.int32),
        ttc=np.array(ttc, np.float64),
        state=np.array(state, np.float64).reshape(-1, 3 * n),
        wrist=np.array(wrist, np.float64).reshape(-1, robot.n_joints - n),
        edge_shield=np.array(shield, np.float64),
        terminals=[t[:3] for t in terms],
        terminal_shield=[t[3] for t in terms],
        tree_discards=dict(tree_why),
        terminal_discards=dict(term_why),
    )


def _connect_plan(inputs: GrowInputs, depth, state, wrist, plane_yz, goal_yz):
    """(node, sorted goal indices) for every node that gets terminal edges, in node order."""
    cfg, n = inputs.tree, inputs.robot.n_arm
    depth = np.asarray(depth)
    q = np.column_stack([np.asarray(state)[:, :n], np.asarray(wrist)])
    d = microns(np.linalg.norm(plane_yz(q)[:, None, :] - goal_yz[None, :, :], axis=2))  # (N, G)
    link = d <= microns(cfg.connect_radius)
    leaves = np.flatnonzero(depth == cfg.max_depth)
    if not cfg.internal_terminals:
        link[depth < cfg.max_depth] = False
    if cfg.root_connects_all:
        link[0] = True
    if cfg.connect_min > 0 and len(leaves):
        nearest = np.argsort(d[leaves], axis=0, kind="stable")[: cfg.connect_min]  # (k, G)
        link[leaves[nearest], np.arange(d.shape[1])[None, :]] = True
    return [(int(i), list(np.flatnonzero(row))) for i, row in enumerate(link) if row.any()]


def default_jobs() -> int:
    """All cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1
