"""``vision_msgs/msg/Detection3DArray`` in (docs/ROS2.md): a ROS 2 detector's 3-D detections as
the project's detection message.

rosbags' Jazzy store has no vision_msgs, so their definitions are registered in it on first use
(:func:`thinkfast.contract.ros_types.vision_typestore`); the CDR codec and the REP-2016 type
hash are rosbags' as for every other type.

One array becomes at most one detection: the ball is one object, so the array's detection with
the highest hypothesis score is taken (the first on ties); its ``bbox.center.position`` [m] is
the ball's centre in the detection's ``header.frame_id`` (the array's when empty), stamped with
the detection's header stamp (the array's when zero). Frames are the project's (``camera`` or
``base``), as for PointStamped.
"""

from __future__ import annotations

import numpy as np

from thinkfast.contract.detection import encode_detection
from thinkfast.contract.ros import RosDecodeError, namespace, seconds
from thinkfast.contract.ros_types import vision_typestore

DETECTION_3D_ARRAY = "vision_msgs/msg/Detection3DArray"


def detections_3d_topic(prefix: str) -> str:
    """``/<prefix>/detections_3d``: where the daemon takes Detection3DArray."""
    return f"{namespace(prefix)}/detections_3d"


def detection_from_array(cdr: bytes, seq: int | None = None) -> bytes | None:
    """The project's JSON detection of the best detection of a Detection3DArray (module doc),
    or None for an array without detections.

    Raises:
        RosDecodeError: ``cdr`` is not a Detection3DArray.
    """
    ts = vision_typestore()
    try:
        msg = ts.deserialize_cdr(bytes(cdr), DETECTION_3D_ARRAY)
    except Exception as exc:  # rosbags raises several kinds on bad bytes
        raise RosDecodeError(f"not a {DETECTION_3D_ARRAY} in CDR ({type(exc).__name__})") from None
    if not msg.detections:
        return None
    scores = [max((r.hypothesis.score for r in d.results), default=0.0) for d in msg.detections]
    best = msg.detections[int(np.argmax(scores))]
    score = max(scores)
    stamp = seconds(best.header.stamp) or seconds(msg.header.stamp)
    frame = best.header.frame_id or msg.header.frame_id
    p = best.bbox.center.position
    if seq is not None and not 0 <= seq < 2**63:
        seq = None
    confidence = float(score) if 0.0 <= score <= 1.0 else None
    return encode_detection(stamp, (p.x, p.y, p.z), frame, confidence=confidence, seq=seq)
