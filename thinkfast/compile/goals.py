"""IK goal grid on the intercept plane.

For every (y, z) of a rectangular grid on the plane x = d, find joint angles that put the shield
centre at (d, y, z) with the shield normal along +x (facing the ball). The grid is solved outwards
from the point nearest home, each point seeded from its solved neighbours and from home, so
neighbouring goals stay on one continuous arm branch (joints 1-3). Among valid candidates the one
nearest home (Euclidean norm of the per-joint times at top speed) wins.

The wrist (joints 4-5; joint_6 is free for a disk) has two equivalent branches (q4 + pi, -q5). With
the shield normal fixed to +x the wrist is singular where the forearm is parallel to +x, a line
that crosses the plane above home; there q4 is not continuous on either branch, so the wrist takes
the branch nearest home point by point.

A point is unreachable when no candidate converges, respects the joint limits and is collision
free; the reason says which test failed.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from typing import NamedTuple

import numpy as np

from thinkfast.compile.config import GoalsConfig
from thinkfast.errors import ConfigError
from thinkfast.robot import fixed_order as fo
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.ik import solve_shield_ik
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import Robot

SHIELD_NORMAL = np.array([1.0, 0.0, 0.0])  # faces the incoming ball (+x in base)
_WRAP = 2.0 * np.pi

PLANE_STEP = 1e-6  # m: distances on the plane are compared in whole micrometres (microns)


def microns(d):
    """Distances [m] as whole micrometres: a goal at exactly a radius, or two points equally
    near, as the symmetric grids make many, are decided the same way whatever the last bits of
    the distances (the first in index order wins a tie)."""
    return np.rint(np.asarray(d) / PLANE_STEP)


class GoalGrid(NamedTuple):
    """Solved grid; arrays are indexed by grid point, row-major over (z, y).

    Attributes:
        plane_distance: plane x in ``base`` [m].
        y, z: grid axes [m], shapes (ny,), (nz,).
        yz: (M, 2) plane coordinates of every point [m], M = ny * nz.
        q: (M, 6) joint angles [rad]; NaN where unreachable.
        reachable: (M,) bool.
        reason: (M,) why a point is unreachable ("" when reachable).
        position_error: (M,) IK centre residual [m] (NaN when unreachable).
        normal_error: (M,) IK normal residual [rad] (NaN when unreachable).
    """

    plane_distance: float
    y: np.ndarray
    z: np.ndarray
    yz: np.ndarray
    q: np.ndarray
    reachable: np.ndarray
    reason: tuple[str, ...]
    position_error: np.ndarray
    normal_error: np.ndarray

    @property
    def goal_index(self) -> np.ndarray:
        """Indices (K,) of reachable points."""
        return np.flatnonzero(self.reachable)


def grid_axes(cfg: GoalsConfig) -> tuple[np.ndarray, np.ndarray]:
    """Grid axes y (ny,), z (nz,) [m]: inclusive ranges, centred when the step does not divide."""

    def axis(lo: float, hi: float) -> np.ndarray:
        n = int(np.floor((hi - lo) / cfg.spacing + 1e-9)) + 1
        start = lo + 0.5 * ((hi - lo) - (n - 1) * cfg.spacing)
        return np.round(start + cfg.spacing * np.arange(n), 12)

    return axis(cfg.y_min, cfg.y_max), axis(cfg.z_min, cfg.z_max)


def _variants(robot: Robot, q: np.ndarray) -> list[np.ndarray]:
    """Equivalent shield poses of ``q``: wrist flip (q4 + pi, -q5) and 2 pi wraps into limits."""
    out = []
    for flip in (False, True):
        c = q.copy()
        if flip:
            c[3] += np.pi
            c[4] = -c[4]
        for j in (0, 3, 5):  # joints whose range allows a 2 pi wrap
            while c[j] > robot.q_upper[j]:
                c[j] -= _WRAP
            while c[j] < robot.q_lower[j]:
                c[j] += _WRAP
        out.append(c)
    return out


def _limit_violation(robot: Robot, q: np.ndarray) -> str:
    names = robot.joint_names
    for j in range(6):
        if q[j] < robot.q_lower[j] or q[j] > robot.q_upper[j]:
            lo, hi = robot.q_lower[j], robot.q_upper[j]
            return f"joint limit: {names[j]} = {q[j]:+.3f} rad outside [{lo:+.3f}, {hi:+.3f}]"
    return ""


def normal_error(normal: np.ndarray) -> float:
    """Angle [rad] between a shield normal (3,) and the plane's, :data:`SHIELD_NORMAL`."""
    return math.atan2(fo.norm(np.cross(normal, SHIELD_NORMAL)), normal[0])


def candidate_problem(robot: Robot, checker: CollisionChecker, q: np.ndarray) -> str:
    """Why the IK solution ``q`` cannot be a goal (or home): a joint limit, else a collision
    (the first pair); "" when it can."""
    why = _limit_violation(robot, q)
    if not why:
        hits = checker.collisions(q)
        why = f"collision: {hits[0][0]} / {hits[0][1]}" if hits else ""
    return why


def solve_goal_grid(
    robot: Robot,
    cfg: GoalsConfig,
    plane_distance: float,
    kin: Kinematics | None = None,
    checker: CollisionChecker | None = None,
) -> GoalGrid:
    """Solve the IK goal grid over the plane.

    Args:
        robot: the robot.
        cfg: grid ranges and spacing.
        plane_distance: plane x in ``base`` [m].
        kin, checker: kinematics and collision checker to reuse (made when omitted).
    """
    kin = kin or Kinematics(robot)
    checker = checker or CollisionChecker(robot, kin)
    y, z = grid_axes(cfg)
    Y, Z = np.meshgrid(y, z)  # rows: z, columns: y
    yz = np.column_stack([Y.ravel(), Z.ravel()])
    M, ny = len(yz), len(y)
    q = np.full((M, 6), np.nan)
    pos_err, ang_err = np.full(M, np.nan), np.full(M, np.nan)
    reason = [""] * M
    scale = 1.0 / robot.v_max  # time at top speed per radian

    home_centre = kin.shield(robot.home).centre
    start = int(np.argmin(microns(np.linalg.norm(yz - home_centre[1:], axis=1))))
    order, seen, queue = [], {start}, deque([start])
    while queue:  # breadth first from the point nearest home
        i = queue.popleft()
        order.append(i)
        r, c = divmod(i, ny)
        for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
            rr, cc = r + dr, c + dc
            k = rr * ny + cc
            if 0 <= rr < len(z) and 0 <= cc < ny and k not in seen:
                seen.add(k)
                queue.append(k)

    for i in order:
        target = np.array([plane_distance, *yz[i]])
        neighbours = _solved_neighbours(i, ny, len(z), q)
        seeds = [q[k] for k in neighbours] + [robot.home.copy()]
        best, best_cost, failure, miss = None, np.inf, "", np.inf
        for seed in seeds:
            res = solve_shield_ik(kin, target, SHIELD_NORMAL, seed)
            if not res.converged:
                miss = min(miss, res.position_error)
                continue
            for cand in _variants(robot, res.q):
                why = candidate_problem(robot, checker, cand)
                if why:
                    if not failure.startswith("collision"):
                        failure = why  # report the deepest test reached
                    continue
                jump = max((np.max(np.abs(cand[:3] - q[k, :3])) for k in neighbours), default=0.0)
                cost = float(fo.norm((cand - robot.home) * scale))
                cost += 1e3 * (jump > cfg.continuity)  # branch switches only as a last resort
                if cost < best_cost:
                    best, best_cost = cand, cost
        if best is None:
            reason[i] = failure or f"out of reach: closest IK iterate misses by {miss * 1e3:.0f} mm"
            continue
        q[i] = best
        pose = kin.shield(best)
        pos_err[i] = fo.norm(pose.centre - target)
        ang_err[i] = normal_error(pose.normal)
    reachable = ~np.isnan(q[:, 0])
    for arr in (q, pos_err, ang_err, reachable, yz):
        arr.setflags(write=False)
    return GoalGrid(plane_distance, y, z, yz, q, reachable, tuple(reason), pos_err, ang_err)


def require_reachable(grid: GoalGrid, source: str) -> None:
    """Refuse a grid without one reachable goal (nothing to compile a tree towards).

    Args:
        grid: the solved grid.
        source: the compile configuration's file name, for the message.

    Raises:
        ConfigError: naming ``plane.distance`` and the ``goals`` ranges, with the reasons counted.
    """
    if grid.reachable.any():
        return
    reasons = Counter(r.split(":")[0] for r in grid.reason)
    why = ", ".join(f"{n} {k}" for k, n in sorted(reasons.items()))
    raise ConfigError(
        source,
        "plane.distance",
        f"no goal is reachable on the plane x = {grid.plane_distance:g} m ({len(grid.reason)} "
        f"points: {why}); move the plane nearer the robot (plane.distance) or the grid into the "
        "arm's reach (goals.y_min/y_max/z_min/z_max)",
    )


def _solved_neighbours(i: int, ny: int, nz: int, q: np.ndarray) -> list[int]:
    r, c = divmod(i, ny)
    out = []
    for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
        rr, cc = r + dr, c + dc
        k = rr * ny + cc
        if 0 <= rr < nz and 0 <= cc < ny and not np.isnan(q[k, 0]):
            out.append(k)
    return out
