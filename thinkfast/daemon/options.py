"""What ``thinkfast-run``'s command line tells the daemon besides the configs: its endpoints
(:class:`Endpoints`) and its first-light modes (:class:`Modes`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Endpoints:
    """I/O options of the daemon (from the command line)."""

    egm_bind: str = "0.0.0.0:6510"
    egm_controller: str | None = None
    egm_handover: float = 1.0
    key_prefix: str = "thinkfast"
    record: Path | None = None
    ros_domain: int | None = None  # also the ROS 2 topics (daemon/ros_edge.py) on this domain
    insecure_zenoh: bool = False  # open a zenoh session others reach without authentication
    link: str = "egm"  # the controller link (thinkfast.link.registry), EGM unless named


@dataclass(frozen=True)
class Modes:
    """First-light options (from the command line; docs/CELL.md).

    Attributes:
        shadow: plan and publish everything, command the position measured at the start.
        go_home: away from home at start-up, move home once the way is checked against the cell
            (without it, or when the way is blocked, the arm holds where it stands, balls are
            ignored and the status says ``fault``: the cell needs an operator).
        speed_scale: the robot's velocity, acceleration and jerk limits are scaled by this
            (already applied to the robot the daemon is given; reported here).
    """

    shadow: bool = False
    go_home: bool = True
    speed_scale: float = 1.0
