"""thinkfast's quantities as Foxglove channels: the live Foxglove view's and the MCAP's.

:class:`ChannelPainter` has the painter methods of the Rerun view
(:class:`~thinkfast.view.rerun_painter.Painter`: ``raw``, ``accepted``, ``belief``,
``crossing``, ``decision``, ``arm``, ``joints``, ``event``, ``status``, ``shield_path``) and turns
each call into encoded messages handed to ``emit(t, topic, data)``:

* the ROS 2 topics of the MCAP export (:data:`thinkfast.view.ros_topics.TOPICS`, CDR by the live
  ROS topics' encoder), when ``ros`` is true;
* the 3D scene on :data:`~thinkfast.view.scene.SCENE_TOPIC` (``foxglove.SceneUpdate``,
  :class:`~thinkfast.view.scene.Scene`): arm and shield, ball belief, crossing, plan, goals;
* the daemon's status message on :data:`STATUS_TOPIC` (JSON), live only.

The live view (``thinkfast-run --foxglove``) emits into the Foxglove SDK's channels; the MCAP
export collects the scene messages of a record (:func:`scene_messages`) beside its ROS 2
messages. :func:`channel_specs` names every channel's schema, one table for both.
"""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np

from thinkfast.contract.ros import encode_string
from thinkfast.view.ros_topics import TOPICS, cdr_joint_state, cdr_point_stamped, schemas
from thinkfast.view.scene import SCENE_TOPIC, Scene, scene_schema

STATUS_TOPIC = "/thinkfast/status"
GOALS_PERIOD = 2.0  # s between repeats of the static goal grid (for clients that join later)
Emit = Callable[[float, str, bytes], None]


def channel_specs(status: bool = True) -> dict[str, tuple[str, str, bytes, str]]:
    """topic -> (schema name, schema encoding, schema data, message encoding) of every channel
    :class:`ChannelPainter` emits on (the status channel only when ``status``)."""
    defs = schemas()
    out = {t: (typ, "ros2msg", defs[typ].encode(), "cdr") for t, typ in TOPICS.items()}
    s = scene_schema()
    out[SCENE_TOPIC] = (s.name, s.encoding, bytes(s.data), "protobuf")
    if status:
        out[STATUS_TOPIC] = ("thinkfast.status", "jsonschema", b'{"type": "object"}', "json")
    return out


class ChannelPainter:
    """The painter methods as messages on channels (module doc).

    Args:
        emit: called with (Unix time [s], topic, encoded message) for every message.
        robot: the robot (joint names and frames, shield).
        plane_x: the blocking plane's distance [m] (x in base).
        goal_yz: goal grid (G, 2) [m] on the plane, or None when unknown.
        ros: also emit the ROS 2 topics (the MCAP export writes those from the record itself).
    """

    def __init__(self, emit: Emit, robot, plane_x: float, goal_yz, ros: bool = True):
        self.emit, self.ros = emit, ros
        self.scene = Scene(robot, plane_x, goal_yz)
        self.names = tuple(robot.joint_names)
        self.next_goals = -np.inf
        self.shield_path = self.scene.shield_path
        self._warm_up(robot)

    def _warm_up(self, robot) -> None:
        """Every method once, emitting nothing: what is made on first use (rosbags' type store
        and its generated serialisers, imports) is made here, before the daemon serves. A cold
        first step measured at milliseconds would otherwise wait for its decaying cost estimate
        (view/live.WAIT_DECAY) and hold the view's queue for seconds."""
        emit, self.emit = self.emit, lambda t, topic, data: None
        try:
            q = np.asarray(robot.any_q, dtype=float)
            self.joints(0.0, q, np.zeros(robot.n_joints), q)
            self.raw(0.0, (1.0, 0.0, 1.0))
            self.belief(0.0, np.r_[1.0, 0.0, 1.0, -1.0, 0.0, 0.0], np.eye(6))
            self.crossing(0.0, np.zeros(3), np.eye(3))
            self.decision(0.0, "", None, -1, np.zeros((2, 3)))
            self.arm(0.0, "commanded", q)
            self.event(0.0, "start", "{}")
            self.status(0.0, {})
        finally:
            self.emit, self.next_goals = emit, -np.inf

    def _scene(self, t: float, *entities) -> None:
        self.emit(t, SCENE_TOPIC, self.scene.update([e for e in entities if e is not None]))

    def raw(self, t: float, p) -> None:
        """A detection as received, in the plane's frame [m] (``base`` without a pose)."""
        if self.ros:
            self.emit(t, "/thinkfast/detections/raw", cdr_point_stamped(t, p))

    def accepted(self, t: float, p) -> None:
        """A detection the intake accepted, in the plane's frame [m] (``base`` without a pose)."""
        if self.ros:
            self.emit(t, "/thinkfast/detections/accepted", cdr_point_stamped(t, p))

    def belief(self, t: float, mean, cov) -> None:
        """Filter belief: mean (6,) [m, m/s], covariance (6, 6)."""
        if self.ros:
            self.emit(t, "/thinkfast/ball/belief", cdr_point_stamped(t, mean))
        self._scene(t, self.scene.ball(mean, cov))

    def crossing(self, t: float, o_mean, o_cov) -> None:
        """Predicted crossing (Y, Z, tau) (3,) [m, m, s] with covariance (3, 3)."""
        if self.ros:
            p = (self.scene.plane_x, float(o_mean[0]), float(o_mean[1]))
            self.emit(t, "/thinkfast/ball/crossing", cdr_point_stamped(t, p))
        self._scene(t, self.scene.crossing(o_mean, o_cov))

    def decision(self, t: float, text: str, value, goal: int, path) -> None:
        """The chosen motion: text, value (or None), goal index (-1 none), shield path (K, 3)."""
        if self.ros:
            obj = {"motion": text, "value": value, "best_goal": int(goal)}
            self.emit(t, "/thinkfast/decisions", encode_string(json.dumps(obj)))
        self._scene(t, self.scene.plan(text, goal, path))

    def arm(self, t: float, which: str, q) -> None:
        """The arm at joints ``q`` (6,) [rad]; the goal grid with it every ``GOALS_PERIOD``."""
        goals = None
        if t >= self.next_goals:
            self.next_goals = t + GOALS_PERIOD
            goals = self.scene.goals()
        self._scene(t, self.scene.arm(which, q), goals)

    def joints(self, t: float, q_cmd, qd_cmd, q_meas) -> None:
        """Commanded positions [rad] and velocities [rad/s], measured positions (or None)."""
        if not self.ros:
            return
        if q_cmd is not None:
            vel = () if qd_cmd is None else qd_cmd
            msg = cdr_joint_state(t, self.names, q_cmd, vel)
            self.emit(t, "/thinkfast/joints/commanded", msg)
        if q_meas is not None:
            self.emit(t, "/thinkfast/joints/measured", cdr_joint_state(t, self.names, q_meas))

    def event(self, t: float, kind: str, detail: str) -> None:
        """One daemon event (kind and JSON detail)."""
        if self.ros:
            text = json.dumps({"kind": kind, "detail": json.loads(detail)})
            self.emit(t, "/thinkfast/events", encode_string(text))

    def status(self, t: float, msg: dict) -> None:
        """The daemon's status message (docs/INTERFACES.md "Status")."""
        self.emit(t, STATUS_TOPIC, json.dumps(msg).encode())

    def close(self) -> None:
        """Nothing buffered here (the sink flushes)."""


def scene_messages(record, robot, plane_x, goal_yz, joint_rate: float = 50.0) -> list:
    """The scene of ``record`` (arm at most ``joint_rate`` per second, beliefs, crossings,
    decisions) as (Unix time [s], :data:`SCENE_TOPIC`, SceneUpdate bytes), in time order."""
    from thinkfast.record.tables import run_config
    from thinkfast.view.replay import log_record

    out: list[tuple[float, str, bytes]] = []
    p = ChannelPainter(lambda t, topic, data: out.append((t, topic, data)), robot,
                       0.0 if plane_x is None else plane_x, goal_yz, ros=False)  # fmt: skip
    log_record(p, record, run_config(record), joint_rate, crossings=plane_x is not None)
    out.sort(key=lambda m: m[0])
    return out
