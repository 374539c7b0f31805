"""What the status message and the start-up summary read off the daemon
(:mod:`thinkfast.daemon.status_text`): the parts and counters of
:class:`thinkfast.daemon.service.Daemon`, typed here so that the status depends on them, not on
the service that runs it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import numpy as np

    from thinkfast.control.config import RunConfig
    from thinkfast.control.core import ControlCore
    from thinkfast.control.intake import Intake
    from thinkfast.control.link import ControllerLink
    from thinkfast.control.safety import SafetySupervisor
    from thinkfast.daemon.home_watch import HomeWatch
    from thinkfast.daemon.options import Modes
    from thinkfast.daemon.zenoh_edge import ZenohIO
    from thinkfast.record.recorder import Recorder
    from thinkfast.robot.model import Robot
    from thinkfast.view.live import DaemonView


class DaemonParts(Protocol):
    """The daemon as its status sees it (read only)."""

    cfg: RunConfig
    robot: Robot
    planner: str
    modes: Modes
    view: DaemonView | None  # the live view (Rerun or Foxglove)
    tree_meta: dict
    tree_fingerprint: str
    recorder: Recorder
    home: HomeWatch
    control: ControlCore
    supervisor: SafetySupervisor
    intake: Intake
    controller_state: dict | None
    planned: tuple[np.ndarray, np.ndarray, str] | None
    link: ControllerLink  # EGM's server, or another link (thinkfast.link.registry)
    plane_x: float  # the plane's distance [m]
    zio: ZenohIO  # or its ROS 2 flavour, daemon/ros_edge.RosIO
    decision_ms: float
    planner_errors: int
    last_throw: dict | None

    def connected(self, now: float) -> bool: ...
