"""The ROS 2 topics of a flight record (:data:`TOPICS`) with their message definitions and
encoders: the MCAP export's (:mod:`thinkfast.view.mcap`) and the live Foxglove view's
(:mod:`thinkfast.view.channels`). Messages and definitions come from the encoder of the live
ROS 2 topics (:mod:`thinkfast.contract.ros`), so a recorded JointState is the bytes the live
topic carries. Points are in the frame ``base`` (:data:`FRAME`, the robot base).
"""

from __future__ import annotations

import numpy as np

from thinkfast.contract.ros import (
    JOINT_STATE,
    POINT_STAMPED,
    STRING,
    encode_joint_state,
    encode_point_stamped,
    typestore,
)

FRAME = "base"
TOPICS = {
    "/thinkfast/joints/commanded": JOINT_STATE,
    "/thinkfast/joints/measured": JOINT_STATE,
    "/thinkfast/detections/raw": POINT_STAMPED,
    "/thinkfast/detections/accepted": POINT_STAMPED,
    "/thinkfast/ball/belief": POINT_STAMPED,
    "/thinkfast/ball/crossing": POINT_STAMPED,
    "/thinkfast/decisions": STRING,
    "/thinkfast/events": STRING,
}


def schemas() -> dict[str, str]:
    """The ROS 2 message definitions (``ros2msg``, with their dependencies, as rosbag2 writes
    them) of every type in :data:`TOPICS`, from the same type store that encodes them."""
    ts = typestore()
    return {typ: ts.generate_msgdef(typ, ros_version=2)[0] for typ in set(TOPICS.values())}


def cdr_joint_state(t: float, names, position, velocity=()) -> bytes:
    """sensor_msgs/msg/JointState at Unix time ``t`` [s]: positions [rad], velocities [rad/s];
    the live topics' encoder (:func:`thinkfast.contract.ros.encode_joint_state`)."""
    vel = None if len(velocity) == 0 else velocity
    return encode_joint_state(t, position, vel, tuple(names))


def cdr_point_stamped(t: float, p, frame: str = FRAME) -> bytes:
    """geometry_msgs/msg/PointStamped at Unix time ``t`` [s]: point (3,) [m] in ``frame``."""
    return encode_point_stamped(t, np.asarray(p, dtype=float)[:3], frame)
