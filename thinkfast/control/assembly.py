"""One assembly of the control core from the configs: the daemon and the lockstep simulator
build the same parts the same way.

Per run (:class:`CoreAssembly`, built once): the runtime view of the action tree (blocks within
shield + ball radius, ``[value]``) and the supervised joint limits (``[safety]
position_margin``). Per core (:meth:`CoreAssembly.core`): the safety supervisor, the detection
intake (``[camera]``, ``[detections]``, ``[[cameras]]``) and the
:class:`~thinkfast.control.core.ControlCore` composing them with an executor
(:meth:`CoreAssembly.executor`, any of its planners).
"""

from __future__ import annotations

from collections.abc import Callable

from thinkfast.control.config import RunConfig
from thinkfast.control.core import ControlCore
from thinkfast.control.executor import Executor
from thinkfast.control.intake import Intake
from thinkfast.control.safety import SafetyLimits, SafetySupervisor, robot_limits
from thinkfast.decide.tree_view import RuntimeTree, runtime_tree
from thinkfast.robot.model import Robot
from thinkfast.tree.action_tree import ActionTree


class CoreAssembly:
    """What every control core of a run shares, and the parts of one core.

    Args:
        tree: the compiled action tree.
        robot: the robot (its limits already scaled where the run scales them).
        cfg: the run configuration.

    Attributes:
        tree: the runtime view of ``tree`` every executor plans on.
        limits: the joint limits the supervisor holds (``[safety] position_margin`` inside).
    """

    def __init__(self, tree: ActionTree, robot: Robot, cfg: RunConfig):
        self.robot, self.cfg = robot, cfg
        self.tree: RuntimeTree = runtime_tree(tree, robot, cfg)
        self.limits: SafetyLimits = robot_limits(robot, cfg.safety.position_margin)

    def executor(
        self,
        planner: str,
        cfg: RunConfig | None = None,
        realtime: bool = False,
        home_on_start: bool = True,
    ) -> Executor:
        """An executor of ``planner`` at home; ``cfg``: another run configuration for it (e.g.
        another ``[hedge] mode``; None: the assembly's). ``realtime``: its planner runs on the
        wall clock (a late solve is dropped); ``home_on_start``: away from home at start, it
        goes home at once (else it holds until told, the daemon's way home checked first)."""
        ex = Executor(self.tree, self.robot, self.cfg if cfg is None else cfg, planner)
        if realtime:
            ex.planner.realtime = True
        ex.home_on_start = home_on_start
        return ex

    def supervisor(self) -> SafetySupervisor:
        """A safety supervisor at home."""
        return SafetySupervisor(self.limits, self.cfg.safety, self.robot.home)

    def core(
        self,
        executor: Executor,
        on_event: Callable[[float, str, dict], None] | None = None,
        shadow: bool = False,
    ) -> ControlCore:
        """The control core around ``executor``: a new supervisor and detection intake.

        Args:
            executor: the planner/executor (from :meth:`executor`).
            on_event: ``on_event(t, kind, detail)`` for things worth logging and recording
                (None: dropped).
            shadow: plan a virtual arm, command the position measured at the start.
        """
        intake = Intake(self.cfg.camera, self.cfg.detections, self.cfg.cameras, self.tree.plane)
        events = {} if on_event is None else {"on_event": on_event}
        return ControlCore(
            executor, self.supervisor(), self.cfg.safety, shadow=shadow, intake=intake, **events
        )
