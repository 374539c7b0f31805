"""The tree's home: robot.toml's, checked to be on the plane, or solved by IK for the region.

Home is where every throw starts: the arm at rest with the shield coplanar with the intercept
plane, best at the centre of the protected region (every goal is then as near as the region
allows, and a ball aimed at the middle is blocked before the arm moves). It belongs to the cell,
not to the arm alone: a home typed into robot.toml for one plane is off another. So the compile
config chooses (``[tree] home``):

- ``"auto"`` (default): robot.toml's ``home`` when it gives one, refused when its shield is off
  the plane (:data:`PLANE_TOLERANCE`, :data:`NORMAL_TOLERANCE`) with the distance; solved when
  robot.toml gives none;
- ``"solve"``: solved, whatever robot.toml says.

A solved home is written into the tree (``parameters.home``, so it is part of the fingerprint);
every command that runs the tree takes it from there
(:func:`thinkfast.tree.robot_match.place_for_tree`).
"""

from __future__ import annotations

import math

import numpy as np

from thinkfast.compile.config import CompileConfig, LoadedConfig
from thinkfast.compile.goals import SHIELD_NORMAL, _variants, candidate_problem, normal_error
from thinkfast.errors import ConfigError
from thinkfast.robot import fixed_order as fo
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.ik import solve_shield_ik
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import Robot, load_robot

PLANE_TOLERANCE = 0.005  # m: a given home's shield centre within this of the plane
NORMAL_TOLERANCE = math.radians(2.0)  # rad: and its normal within this of the plane's normal

# Seeds of the home solve, in the positioning joints (joint_1 is aimed at the target, the wrist
# starts straight): elbow-up configurations of a 6-axis ABB arm, from upright to leaning forward.
_SEEDS_23 = ((0.0, 0.0), (-0.3, 0.3), (0.3, -0.3), (0.5, 0.3), (-0.5, 0.6), (0.2, 0.6))


def home_error(robot: Robot, q: np.ndarray, distance: float) -> tuple[float, float]:
    """How far ``q``'s shield is from coplanar with the plane ``x = distance``: the centre's
    distance from the plane [m] and the angle of its normal from the plane's [rad] (both in the
    robot's frame: the plane's when placed)."""
    pose = Kinematics(robot).shield(np.asarray(q, dtype=np.float64))
    return abs(float(pose.centre[0]) - distance), float(normal_error(pose.normal))


def region_centre(cfg: CompileConfig) -> np.ndarray:
    """The protected region's centre on the plane, in the plane's frame [m] (3,)."""
    (y0, y1), (z0, z1) = cfg.goals.region()
    return np.array([cfg.plane.distance, 0.5 * (y0 + y1), 0.5 * (z0 + z1)])


def solve_home(robot: Robot, cfg: CompileConfig, source: str = "compile config") -> np.ndarray:
    """Home by IK: the shield centre at the region's centre, normal facing the ball, at rest.

    Among converged candidates (every seed, both wrist branches) within the joint limits and free
    of collisions, the one nearest the zero configuration in time at top speed wins; joint_6 is 0
    (it turns the disk about its own axis). Deterministic: fixed seeds, fixed order.

    Args:
        robot: the robot placed in the config's plane (:func:`placed_robot`'s frame).
        cfg: the compile configuration (plane and goal region).
        source: the config's path, for the message.

    Raises:
        ConfigError: no seed reaches the centre (names ``goals`` and the closest miss).
    """
    kin = Kinematics(robot)
    checker = CollisionChecker(robot, kin)
    target = region_centre(cfg)
    base = cfg.plane.pose().to_base(target)
    q1 = math.atan2(float(base[1]), float(base[0]))
    scale = 1.0 / np.asarray(robot.v_max)
    n = robot.n_joints
    best, best_cost, miss, why = None, math.inf, math.inf, ""
    for q2, q3 in _SEEDS_23:
        seed = np.zeros(n)
        seed[:3] = (q1, q2, q3)
        res = solve_shield_ik(kin, target, SHIELD_NORMAL, seed)
        if not res.converged:
            miss = min(miss, res.position_error)
            continue
        for cand in _variants(robot, res.q):
            problem = candidate_problem(robot, checker, cand)
            if problem:
                why = why or problem
                continue
            cost = float(fo.norm(cand * scale))
            if cost < best_cost:
                best, best_cost = cand, cost
    if best is None:
        detail = why or f"out of reach: closest IK iterate misses by {miss * 1e3:.0f} mm"
        y, z = target[1:]
        raise ConfigError(
            source,
            "goals",
            f"no home: the shield cannot stand at the region's centre (y {y:.3f}, z {z:.3f} m "
            f"on the plane at {cfg.plane.distance:g} m): {detail}; move the region or the plane",
        )
    return best


def resolve_home(robot: Robot, cfg: CompileConfig, source: str = "compile config") -> Robot:
    """``robot`` with the home the tree is compiled from (see the module doc): robot.toml's
    under ``"auto"`` (not checked here: :func:`check_home`, once the goal grid is known to
    be reachable, so that a plane out of reach is said first), else the solved one.

    Raises:
        ConfigError: no home can be solved.
    """
    if cfg.tree.home == "auto" and robot.home is not None:
        return robot
    return robot.with_home(solve_home(robot, cfg, source))


def placed_robot(loaded: LoadedConfig) -> Robot:
    """The robot of ``loaded``, placed in its plane (``Robot.placed``), with the tree's home
    (:func:`resolve_home`): every pose the compiler computes is in the plane's frame.

    Raises:
        ConfigError: no home can be solved. robot.toml's home on the plane is checked by
            :func:`check_home`, after the goal grid.
    """
    placed = load_robot(loaded.robot_path).placed(loaded.config.plane.pose())
    return resolve_home(placed, loaded.config, str(loaded.path))


def check_home(robot: Robot, cfg: CompileConfig, source: str = "compile config") -> None:
    """Refuse a home read from robot.toml whose shield is off the plane (a solved one is on it).

    Raises:
        ConfigError: names ``tree.home``, the distance, the angle and the fix.
    """
    if robot.home is not None and not robot.home_solved:
        off, ang = home_error(robot, robot.home, cfg.plane.distance)
        if off > PLANE_TOLERANCE or ang > NORMAL_TOLERANCE:
            raise ConfigError(
                source,
                "tree.home",
                f"robot.toml's home ({robot.toml_path}) puts the shield {off * 1e3:.1f} mm off "
                f"the plane at {cfg.plane.distance:g} m and its normal {math.degrees(ang):.1f} deg "
                f"off the plane's (allowed {PLANE_TOLERANCE * 1e3:g} mm, "
                f'{math.degrees(NORMAL_TOLERANCE):g} deg): set [tree] home = "solve" to solve '
                "it for this plane's region, or fix robot.toml's home",
            )
