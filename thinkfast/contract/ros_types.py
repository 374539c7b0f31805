"""The rosbags type stores of the ROS 2 messages (docs/ROS2.md): ROS 2 Jazzy's
(:func:`typestore`: message definitions, CDR codec, REP-2016 type hashes), and the same store
with vision_msgs' detection types registered (:func:`vision_typestore`).

rosbags' Jazzy store has no vision_msgs, so their definitions (:data:`VISION_MSGS`, vision_msgs
4.1.1, the Jazzy release: fields only, comments left out, as the type hash covers fields only) are
registered in it on first use. :mod:`thinkfast.contract.ros` encodes, decodes and names keys with
these stores, :mod:`thinkfast.contract.ros_vision` decodes Detection3DArray with the second.

``rosbags`` is the optional extra ``ros`` (``pip install 'thinkfast[ros]'``); without it,
:func:`typestore` raises a :class:`ConfigError` that says so.
"""

from __future__ import annotations

import functools

from thinkfast.errors import ConfigError

VISION_MSGS = {  # vision_msgs 4.1.1 (ROS 2 Jazzy), msg/*.msg without comments
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
        "vision_msgs/BoundingBox3D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection3DArray": (
        "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n"
    ),
}


@functools.cache
def typestore():
    """The rosbags type store of ROS 2 Jazzy (message definitions, CDR codec, type hashes).

    Raises:
        ConfigError: rosbags is not installed (the ``ros`` extra).
    """
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ConfigError(
            "--ros-domain", None, "needs rosbags: pip install 'thinkfast[ros]'"
        ) from None
    return get_typestore(Stores.ROS2_JAZZY)


@functools.cache
def vision_typestore():
    """The project's rosbags type store with vision_msgs' detection types registered."""
    from rosbags.typesys import get_types_from_msg

    ts = typestore()
    types = {}
    for name, text in VISION_MSGS.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts
