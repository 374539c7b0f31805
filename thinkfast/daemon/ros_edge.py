"""ROS 2 edge of the daemon (``thinkfast-run --ros-domain N``; docs/ROS2.md).

:class:`RosIO` is the daemon's :class:`ZenohIO` plus, on the same zenoh session, the ROS 2 topics
in rmw_zenoh's layout (:mod:`thinkfast.contract.ros`):

* in: ``/<prefix>/detections`` (``geometry_msgs/msg/PointStamped``). Each sample becomes the
  project's JSON detection (:func:`detection_from_point`: stamp, position, frame from
  ``frame_id``, ``seq`` from the attachment) and joins the JSON detections in :meth:`drain`:
  the same intake, the same counters and drops. A sample that is not a PointStamped in CDR is
  handed on as it is, so the intake refuses it (``not_json`` or ``not_utf8``) and counts it.
* in: ``/<prefix>/detections_3d`` (``vision_msgs/msg/Detection3DArray``): the best detection
  of each array the same way (:func:`~thinkfast.contract.ros_vision.detection_from_array`);
  an array without detections is counted ``empty`` and dropped.
* out, with every setpoint mirrored: ``/<prefix>/joint_commands`` (the commanded position and
  velocity) and ``/<prefix>/joint_states`` (the measured position of the EGM feedback it
  answers), ``sensor_msgs/msg/JointState``;
* out, with every status: ``/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``); the JSON
  status gains a ``ros`` key (domain, samples received, undecodable).

Everything runs where the JSON edge runs (between EGM replies, never inside one).
"""

from __future__ import annotations

import zenoh

from thinkfast.contract import ros, ros_diagnostics, ros_vision, ros_zenoh
from thinkfast.contract.zenoh_session import drain_samples
from thinkfast.daemon.zenoh_edge import QUEUE, ZenohIO


class RosIO(ZenohIO):
    """:class:`ZenohIO` with the ROS 2 topics of ``prefix`` on domain ``domain``.

    Raises:
        ConfigError: ``domain`` is not a ROS domain id, ``prefix`` not a ROS namespace, or
            rosbags is missing.
    """

    def __init__(self, conf: zenoh.Config, prefix: str, domain: int, insecure: bool = False):
        ros.check_options(domain, prefix)  # before any session opens
        self.topics = ros.topics(prefix)
        super().__init__(conf, prefix, insecure)
        self.domain = domain
        self.node = ros_zenoh.RosNode(self.session, domain, ros.NODE_RUN)
        self.sub_ros = self.node.subscriber(
            self.topics.detections, ros.POINT_STAMPED, zenoh.handlers.FifoChannel(QUEUE)
        )
        ros_vision.vision_typestore()  # the Detection3DArray definitions, before subscribing
        self.sub_vision = self.node.subscriber(
            ros_vision.detections_3d_topic(prefix),
            ros_vision.DETECTION_3D_ARRAY,
            zenoh.handlers.FifoChannel(QUEUE),
        )
        self.pub_commands = self.node.publisher(self.topics.joint_commands, ros.JOINT_STATE)
        self.pub_states = self.node.publisher(self.topics.joint_states, ros.JOINT_STATE)
        self.pub_diagnostics = self.node.publisher(self.topics.diagnostics, ros.DIAGNOSTIC_ARRAY)
        self.received = 0
        self.undecodable = 0
        self.empty = 0  # Detection3DArray without detections

    def describe(self) -> dict:
        ros_part = {"ros_domain": self.domain, "ros_topics": self.topics._asdict()}
        return {**super().describe(), **ros_part}

    def drain(self, limit: int = 256) -> list[bytes]:
        """JSON detections, then the PointStamped ones and the Detection3DArray ones as JSON
        (at most ``limit`` of each); on a secured session, each from its camera's node."""
        out = super().drain(limit)
        for sub, convert in ((self.sub_ros, ros.detection_from_point),
                             (self.sub_vision, ros_vision.detection_from_array)):  # fmt: skip
            for sample in drain_samples(sub, limit):
                payload = self._convert(sample, convert)
                if payload is not None and (self.gate is None or self.gate.admit(sample, payload)):
                    out.append(payload)
        return out

    def _convert(self, sample, convert) -> bytes | None:
        self.received += 1
        cdr = sample.payload.to_bytes()
        att = sample.attachment
        try:
            seq = ros_zenoh.decode_attachment(None if att is None else att.to_bytes()).seq
        except ros.RosDecodeError:
            seq = None  # the attachment only helps ordering; a detection does not need it
        try:
            payload = convert(cdr, seq)
        except ros.RosDecodeError:
            self.undecodable += 1
            return cdr  # refused and counted by the intake
        if payload is None:
            self.empty += 1
        return payload

    def publish_setpoint(self, stamp: float, q, qd, mode: str, q_meas=None) -> None:
        super().publish_setpoint(stamp, q, qd, mode, q_meas)
        self.pub_commands.put(ros.encode_joint_state(stamp, q, qd))
        if q_meas is not None:
            self.pub_states.put(ros.encode_joint_state(stamp, q_meas))

    def publish_status(self, status: dict) -> None:
        status = {**status, "ros": self.as_dict()}
        super().publish_status(status)
        self.pub_diagnostics.put(ros_diagnostics.encode_diagnostics(status))

    def as_dict(self) -> dict:
        """ROS counters for the status."""
        return {"domain": self.domain, "received": self.received, "undecodable": self.undecodable,
                "empty": self.empty}  # fmt: skip

    def close(self) -> None:
        self.node.close()
        super().close()
