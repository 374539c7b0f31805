"""Compile configuration: one frozen dataclass per stage, loaded from one TOML file."""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

from thinkfast.config import from_dict, load_toml, spec
from thinkfast.contract.frames import PlanePose
from thinkfast.errors import ConfigError


@dataclass(frozen=True)
class PlaneConfig:
    """The intercept plane: x = distance in the ``plane`` frame, the shield facing +x (towards
    the ball). Without a pose (yaw, offset, base_height 0) ``plane`` is ``base``; with one, the
    plane is turned and moved in ``base`` and the goal ranges are the plane's own (y along it,
    z above the floor): :class:`thinkfast.contract.frames.PlanePose`, docs/ROBOTS.md."""

    distance: float = spec(0.8, lo=0.0, lo_open=True, unit="m", doc="plane distance from base")
    yaw: float = spec(
        0.0,
        lo=-math.pi / 2,
        hi=math.pi / 2,
        unit="rad",
        doc="the plane's normal turned about base z, radians within a quarter turn (so that "
        "degrees are refused)",
    )
    offset: float = spec(
        0.0, lo=-5.0, hi=5.0, unit="m", doc="the plane's centre line, left of the base's axis"
    )
    base_height: float = spec(
        0.0, lo=-5.0, hi=5.0, unit="m", doc="the base's origin above the floor (a pedestal)"
    )

    def pose(self) -> PlanePose:
        """The plane as a pose in ``base`` (the frame transform of the whole run)."""
        return PlanePose(self.distance, self.yaw, self.offset, self.base_height)

    def parameters(self) -> dict:
        """The plane as a tree records it: the pose keys only where the plane has a pose, so
        that a plane without one is the same tree as before poses existed."""
        pose = self.pose()
        return {"distance": self.distance} if pose.identity else pose.as_dict()


@dataclass(frozen=True)
class GoalsConfig:
    """Rectangular goal grid over the plane (inclusive ranges)."""

    y_min: float = spec(-0.9, unit="m", doc="lowest base y of the grid")
    y_max: float = spec(0.9, unit="m", doc="highest base y of the grid")
    z_min: float = spec(0.25, unit="m", doc="lowest base z of the grid")
    z_max: float = spec(1.75, unit="m", doc="highest base z of the grid")
    spacing: float = spec(0.15, lo=0.0, lo_open=True, unit="m", doc="grid step in y and z")
    continuity: float = spec(
        1.0,
        lo=0.0,
        lo_open=True,
        unit="rad",
        doc="largest joint 1-3 jump to a solved neighbour before a branch switch is assumed",
    )

    def region(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The protected region, ``((y_min, y_max), (z_min, z_max))`` [m] on the plane (a
        tree's ``Provenance.region``)."""
        return (self.y_min, self.y_max), (self.z_min, self.z_max)


@dataclass(frozen=True)
class TreeConfig:
    """Action tree growth (the paper's Algorithm 1) on joints 1-3."""

    eps: float = spec(0.1, lo=0.0, lo_open=True, unit="s", doc="maximum primitive duration")
    max_depth: int = spec(3, lo=1, hi=8, doc="depth of the tree of cut primitives")
    subgoal_spacing: float = spec(
        0.6,
        lo=0.0,
        lo_open=True,
        unit="m",
        doc="steering sub-goal grid step, through home (snapped to goals)",
    )
    connect_radius: float = spec(
        0.3,
        lo=0.0,
        unit="m",
        doc="leaves connect to every goal this near (shield on the plane, to the micrometre)",
    )
    connect_min: int = spec(
        2, lo=0, doc="every goal also connects to at least this many nearest leaves"
    )
    internal_terminals: bool = spec(
        True, doc="nodes above max_depth also connect to goals within connect_radius"
    )
    root_connects_all: bool = spec(
        True, doc="the root connects to every goal (direct minimum-time moves from home)"
    )
    collision_resolution: float = spec(
        0.02, lo=0.0, lo_open=True, unit="m", doc="largest motion of any robot point between checks"
    )
    position_margin: float = spec(
        0.01, lo=0.0, unit="rad", doc="primitives stay this far inside the URDF position limits"
    )
    sample_dt: float = spec(
        0.002, lo=0.0, lo_open=True, hi=0.01, unit="s", doc="sampling step along a primitive"
    )
    home: str = spec(
        "auto",
        choices=("auto", "solve"),
        doc="home: robot.toml's when it gives one, checked on the plane (auto), else solved by IK "
        "for the shield at the region's centre (solve); thinkfast.compile.home",
    )
    shield_dt: float = spec(
        0.02,
        lo=0.001,
        hi=0.1,
        unit="s",
        doc="largest sample spacing of the stored shield paths (eps / a whole number is used)",
    )


@dataclass(frozen=True)
class CompileConfig:
    """Everything ``thinkfast-compile`` needs; ``robot`` is relative to the config file."""

    robot: str = spec("../robots/irb1600/robot.toml", doc="robot.toml path")
    plane: PlaneConfig = spec(PlaneConfig())
    goals: GoalsConfig = spec(GoalsConfig())
    tree: TreeConfig = spec(TreeConfig())


@dataclass(frozen=True)
class LoadedConfig:
    """A validated config with its provenance."""

    config: CompileConfig
    path: Path
    text: str
    sha256: str
    robot_path: Path

    def parameters(self, robot) -> dict:
        """The resolved configuration as a tree records it (``parameters``): every key, except
        the plane's pose keys where it has none and ``tree.home`` where it is ``"auto"``, so that
        a config without them is the same tree as before they existed; ``home`` holds a solved
        home [rad] (``robot``'s, from :func:`thinkfast.compile.home.placed_robot`)."""
        from thinkfast.config import to_dict

        out = {**to_dict(self.config), "plane": self.config.plane.parameters()}
        if out["tree"].get("home") == "auto":
            out["tree"] = {k: v for k, v in out["tree"].items() if k != "home"}
        if robot.home_solved:
            out["home"] = [float(x) for x in robot.home]
        return out


def check_compile_config(cfg: CompileConfig, source: str, prefix: str = "") -> CompileConfig:
    """``cfg`` when its values agree with each other (the goal ranges are not empty).

    Raises:
        ConfigError: naming ``source`` and the key (under ``prefix``, e.g. ``compile``).
    """
    g, pre = cfg.goals, f"{prefix}." if prefix else ""
    if cfg.plane.base_height < 0.0:
        raise ConfigError(
            source, f"{pre}plane.base_height", "must be >= 0: the base stands on or above the floor"
        )
    if g.y_max < g.y_min:
        raise ConfigError(source, f"{pre}goals.y_max", f"must be >= goals.y_min ({g.y_min:g})")
    if g.z_max < g.z_min:
        raise ConfigError(source, f"{pre}goals.z_max", f"must be >= goals.z_min ({g.z_min:g})")
    return cfg


def load_compile_config(path: str | Path) -> LoadedConfig:
    """Read and validate a compile TOML file.

    Raises:
        ConfigError: unreadable file, invalid TOML, unknown key, wrong type or impossible value.
    """
    path = Path(path)
    data = load_toml(path)
    cfg = check_compile_config(from_dict(CompileConfig, data, str(path)), str(path))
    text = path.read_text(encoding="utf-8")
    return LoadedConfig(
        config=cfg,
        path=path,
        text=text,
        sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(),
        robot_path=(path.parent / cfg.robot).resolve(),
    )
