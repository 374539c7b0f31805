"""Sampled shield-centre paths of every compiled edge (tree file v2, ``/edges/shield`` and
``/terminals/shield``).

The runtime scores a compiled branch by the probability that its shield meets the ball, moving
or at rest (:mod:`thinkfast.decide.path_value`); it needs the shield centre along every edge.
Each primitive is recomputed with Ruckig from its stored start state (exactly as the compiler and
``verify`` do) and sampled every ``dt`` from its start: a tree edge at ``0, dt, ..., eps`` (a
primitive that reached its target holds there), a terminal edge at ``0, dt, ...`` up to the
longest terminal edge of the tree, held at its goal after its own duration. The shield centre
follows joints 1-3 with the coplanar wrist rule (normal +x): wrist centre plus the shield offset
(:class:`thinkfast.robot.shield_path.ShieldSampler`).
"""

from __future__ import annotations

import math

import numpy as np

from thinkfast.errors import NoSolutionError
from thinkfast.robot.batch_traj import TrajectoryTable
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.robot.steering import Steering

BATCH = 256  # terminal edges sampled per numpy pass (its temporaries stay in the cache)


def sample_spacing(eps: float, largest: float) -> float:
    """The spacing [s] used for shield paths: ``eps`` over the fewest whole steps that are no
    longer than ``largest`` (so tree edges start and end on samples)."""
    return eps / math.ceil(eps / largest - 1e-9)


def steps_per_edge(eps: float, dt: float) -> int:
    """Samples steps along one tree edge: ``eps / dt``, which must be a whole number.

    Raises:
        ValueError: ``eps`` is not a multiple of ``dt`` (to 1e-9).
    """
    k = round(eps / dt)
    if k < 1 or abs(k * dt - eps) > 1e-9:
        raise ValueError(f"tree.shield_dt {dt} s does not divide tree.eps {eps} s")
    return int(k)


def centres_at(sampler: ShieldSampler, table: TrajectoryTable, rows, times) -> np.ndarray:
    """Shield centres [m] (R, T, 3) of ``table``'s trajectories ``rows`` (R,) at ``times`` (T,)
    [s], each time clipped to ``[0, duration]`` of its trajectory (held at the end)."""
    rows = np.asarray(rows, dtype=np.intp)
    if len(rows) == 0:
        return np.empty((0, len(times), 3))
    owner = np.repeat(rows, len(times))
    t = np.minimum(np.maximum(np.tile(times, len(rows)), 0.0), table.duration[owner])
    return sampler.centres(table.positions(owner, t).reshape(len(rows), len(times), 3))


def terminal_samples(duration: float, dt: float) -> int:
    """Samples every ``dt`` from 0 that reach past ``duration`` [s]: the last one is held."""
    return math.ceil(duration / dt - 1e-9) + 2


def terminal_centres(
    sampler: ShieldSampler, table: TrajectoryTable, rows, dt: float
) -> list[np.ndarray]:
    """Shield centres [m] of ``table``'s trajectories ``rows`` every ``dt`` from 0 to one sample
    past each one's end, ``(terminal_samples(duration, dt), 3)`` each (the rows of
    :func:`edge_shield_paths`' ``term`` before the held end: :func:`pad_terminals`)."""
    rows = np.asarray(rows, dtype=np.intp)
    counts = [terminal_samples(float(d), dt) for d in table.duration[rows].tolist()]
    if not counts:
        return []
    owner = np.repeat(rows, counts)
    t = np.concatenate([np.arange(n) for n in counts]) * dt  # as np.arange(s) * dt
    t = np.minimum(np.maximum(t, 0.0), table.duration[owner])
    c = sampler.centres(table.positions(owner, t))
    return np.split(c, np.cumsum(counts)[:-1])


def pad_terminals(paths: list[np.ndarray], longest: float, dt: float) -> np.ndarray:
    """The ``term`` array (T, S, 3) of :func:`edge_shield_paths` from the rows of
    :func:`terminal_centres` (their last sample held; ``longest`` the longest duration [s])."""
    s = math.ceil(longest / dt - 1e-9) + 1 if paths else 1
    term = np.empty((len(paths), s, 3))
    for j, c in enumerate(paths):
        n = min(len(c), s)
        term[j, :n] = c[:n]
        term[j, n:] = c[-1]
    return term


def _positions(trajs: list, times: np.ndarray) -> np.ndarray:
    """Joints 1-3 [rad] (M, T, 3) of ``trajs`` at ``times`` (T,) clipped to each duration."""
    if not trajs:
        return np.empty((0, len(times), 3))
    table = TrajectoryTable(trajs)
    owner = np.repeat(np.arange(len(trajs)), len(times))
    t = np.minimum(np.maximum(np.tile(times, len(trajs)), 0.0), table.duration[owner])
    return table.positions(owner, t).reshape(len(trajs), len(times), 3)


def edge_shield_paths(
    robot,
    node_parent: np.ndarray,
    node_state: np.ndarray,
    edge_target: np.ndarray,
    term_node: np.ndarray,
    term_goal: np.ndarray,
    term_duration: np.ndarray,
    goal_q: np.ndarray,
    subgoal_goal: np.ndarray,
    eps: float,
    dt: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Shield centres [m] in ``base`` along every tree edge and terminal edge.

    Args:
        robot: the robot the tree was compiled for.
        node_parent, node_state, edge_target: the tree's node arrays (N rows).
        term_node, term_goal, term_duration: the terminal arrays (T rows).
        goal_q, subgoal_goal: goals and steering sub-goals.
        eps: tree edge duration [s]. dt: sample spacing [s] (divides ``eps``).

    Returns:
        ``edge`` (N, eps / dt + 1, 3): row i along the primitive into node i (row 0, the root's
        stub, stays at home); ``term`` (T, S, 3) with S = ceil(longest terminal / dt) + 1.

    Raises:
        NoSolutionError: Ruckig cannot recompute a stored primitive.
        ValueError: ``dt`` does not divide ``eps``.
    """
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    sampler = ShieldSampler(robot)
    k = steps_per_edge(eps, dt)
    t_edge = np.arange(k + 1) * dt
    n = len(node_parent)
    q = np.empty((n, k + 1, 3))
    q[0] = node_state[0, :3]
    sub_q = goal_q[subgoal_goal, :3]
    trajs = [steer.steer(node_state[node_parent[i]], sub_q[edge_target[i]]) for i in range(1, n)]
    q[1:] = _positions(trajs, np.minimum(t_edge, eps))
    longest = float(np.max(term_duration)) if len(term_duration) else 0.0
    s = math.ceil(longest / dt - 1e-9) + 1
    t_term = np.arange(s) * dt
    term = np.empty((len(term_node), s, 3))
    for lo in range(0, len(term_node), BATCH):  # the FK per batch is the same, bit for bit
        trajs = [
            steer.steer(node_state[term_node[j]], goal_q[term_goal[j], :3])
            for j in range(lo, min(lo + BATCH, len(term_node)))
        ]
        term[lo : lo + len(trajs)] = sampler.centres(_positions(trajs, t_term))
    return sampler.centres(q), term


__all__ = ["NoSolutionError", "edge_shield_paths", "sample_spacing", "steps_per_edge"]
