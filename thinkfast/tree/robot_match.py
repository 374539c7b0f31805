"""The robot a tree was compiled for: found from the tree's provenance, and checked.

A tree is only valid for the robot description it was compiled against (its joint limits, its
links, its shield): every command that meets a tree and a robot (the daemon, the simulators,
calibration) loads the robot through :func:`robot_for_tree`, or checks the one it was given with
:func:`check_robot`, so a run never uses another robot's limits in silence.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from thinkfast.errors import RobotModelError, TreeFileError
from thinkfast.robot.model import Robot, default_robot_path, load_robot
from thinkfast.tree.provenance import Provenance


def _ident(name: Any, urdf: Any, toml: Any) -> str:
    return f"{name} (urdf {str(urdf)[:12]}, robot.toml {str(toml)[:12]})"


def check_robot(meta: Mapping[str, Any], robot: Robot, where: str = "tree") -> None:
    """Refuse ``robot`` unless it is the robot the tree of ``meta`` was compiled for: same
    name (when the tree records one), URDF hash and robot.toml hash.

    Args:
        meta: the tree's root attributes (``ActionTree.meta``).
        robot: the loaded robot.
        where: the tree's name in the message (its path).

    Raises:
        RobotModelError: one line naming the tree's robot and the one loaded (and its path).
    """
    name = meta.get("robot_name")
    urdf, toml = meta.get("urdf_sha256"), meta.get("robot_toml_sha256")
    same = (
        (name is None or str(name) == robot.name)
        and urdf == robot.urdf_sha256
        and toml == robot.toml_sha256
    )
    if not same:
        raise RobotModelError(
            f"another robot than the tree's: {where} was compiled for "
            f"{_ident(name or '?', urdf, toml)}; the robot loaded is "
            f"{_ident(robot.name, robot.urdf_sha256, robot.toml_sha256)} from "
            f"{robot.toml_path}: pass the tree's robot or recompile"
        )


def tree_robot_path(meta: Mapping[str, Any]) -> Path | None:
    """robot.toml named by the tree's compile configuration, if it still exists (None for a
    tree without readable provenance)."""
    try:
        return Provenance.of(meta).robot_toml()
    except TreeFileError:
        return None


def robot_for_tree(
    meta: Mapping[str, Any],
    where: str = "tree",
    given: str | Path | None = None,
    *,
    placed: bool = True,
) -> Robot:
    """The robot to run the tree of ``meta`` with, checked by :func:`check_robot`.

    Args:
        meta: the tree's root attributes (``ActionTree.meta``).
        where: the tree's name in messages (its path).
        given: robot.toml asked for (a run config's ``robot``, a flag); None or "": the tree's
            robot.toml where it still exists, else the default robot.
        placed: in the tree's plane (:func:`place_for_tree`, every run); False: in ``base``
            with the tree's home (calibration, which works in the robot's own frame).

    Raises:
        ConfigError, RobotModelError: the robot cannot be loaded, or is not the tree's.
    """
    path = Path(given) if given else tree_robot_path(meta) or default_robot_path()
    robot = load_robot(path)
    check_robot(meta, robot, str(where))
    return place_for_tree(meta, robot, where) if placed else home_for_tree(meta, robot, where)


def home_for_tree(meta: Mapping[str, Any], robot: Robot, where: str = "tree") -> Robot:
    """``robot`` with the tree's home: the solved one it holds (``parameters.home``), else
    robot.toml's.

    Raises:
        TreeFileError: the tree's provenance is unreadable.
        RobotModelError: neither the tree nor robot.toml gives a home.
    """
    return _with_home(Provenance.of(meta, str(where)), robot, where)


def _with_home(prov: Provenance, robot: Robot, where: str) -> Robot:
    home = prov.home
    if home is not None:
        return robot.with_home(home)
    if robot.home is None:
        raise RobotModelError(
            f"{where} names no home and {robot.toml_path} gives none: recompile the tree"
        )
    return robot


def place_for_tree(meta: Mapping[str, Any], robot: Robot, where: str = "tree") -> Robot:
    """``robot`` (checked to be the tree's) in the tree's cell: placed in the tree's plane
    (``Robot.placed``), so that every pose of the run is in the plane's frame, with the tree's
    home (a solved one, ``parameters.home``; else robot.toml's). A robot placed already must be
    in the same plane.

    Raises:
        TreeFileError: the tree's provenance is unreadable.
        RobotModelError: ``robot`` is placed in another plane, or has no home the tree names.
    """
    prov = Provenance.of(meta, str(where))
    robot = _with_home(prov, robot, where)
    plane = prov.plane
    if robot.placement is not None:
        if robot.placement.identity != plane.identity or (
            not plane.identity and robot.placement != plane
        ):
            raise RobotModelError(
                f"another plane than the tree's: {where} was compiled for {plane}; the robot "
                f"is placed in {robot.placement}"
            )
        return robot
    return robot.placed(plane)
