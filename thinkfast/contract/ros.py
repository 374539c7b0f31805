"""ROS 2 messages on zenoh, laid out as ``rmw_zenoh`` lays them out (docs/ROS2.md).

A ROS 2 node that runs ``rmw_zenoh_cpp`` and reaches our zenoh session sees the topics published
here, and its publishers reach our subscribers, without ROS installed on our side. A topic's key
expression is ``<domain_id>/<name>/<DDS type name>/<type hash>``; the payload is CDR, written
and read by ``rosbags`` (:func:`typestore`); attachments and liveliness tokens are
:mod:`thinkfast.contract.ros_zenoh`. Units (REP-103/105): positions [m] in ``camera`` or
``base``, joint positions [rad] and velocities [rad/s].

``rosbags`` is the optional extra ``ros`` (``pip install 'thinkfast[ros]'``); without it, using
this module raises a :class:`ConfigError` that says so.

The layout, the type hash, frames and units in full: docs/ROS2.md, "The zenoh layout".
"""

from __future__ import annotations

import math
import re
from typing import NamedTuple

import numpy as np

from thinkfast.contract.detection import Detection, encode_detection, parse_detection
from thinkfast.contract.ros_types import typestore, vision_typestore
from thinkfast.errors import ConfigError, ThinkfastError

POINT_STAMPED = "geometry_msgs/msg/PointStamped"
JOINT_STATE = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 7))  # the URDF's (ROS-Industrial names)
JOINT_FRAME = "base_link"
DETECTION_FRAMES = ("camera", "base")  # header.frame_id of a detection
NODE_RUN, NODE_DETECT = "thinkfast_run", "thinkfast_detect"

MAX_DOMAIN = 232  # ROS_DOMAIN_ID: 0..232 is what every ROS 2 RMW accepts
_NAME_TOKEN = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


class RosDecodeError(ThinkfastError):
    """A payload is not the CDR of the message type expected, or an attachment is not
    rmw_zenoh's. The message says which."""


# ----------------------------------------------------------------------------- names and keys
def check_domain(domain: int) -> int:
    """``domain`` if it is a ROS domain id (0..232), else a :class:`ConfigError`."""
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= MAX_DOMAIN:
        raise ConfigError("--ros-domain", None, f"{domain!r} is not a ROS domain id (0..232)")
    return domain


def namespace(prefix: str) -> str:
    """The ROS namespace of the project's topics: ``/<prefix>`` (``/thinkfast`` by default).

    Raises:
        ConfigError: ``prefix`` is not a valid ROS name (letters, digits, ``_``, ``/``
            separated tokens that start with a letter).
    """
    parts = prefix.strip("/").split("/")
    if not all(_NAME_TOKEN.fullmatch(p) for p in parts):
        raise ConfigError(
            "--key-prefix", None, f"{prefix!r} is not a valid ROS namespace (with --ros-domain: "
            "tokens of letters, digits and _ that start with a letter, separated by /)",
        )  # fmt: skip
    return "/" + "/".join(parts)


def check_options(domain: int, prefix: str) -> None:
    """Refuse, with one :class:`ConfigError` naming the option, a ROS domain id out of 0..232,
    a key prefix that is no ROS namespace, or a missing rosbags."""
    check_domain(domain)
    namespace(prefix)
    typestore()


class Topics(NamedTuple):
    """Fully qualified ROS topic names of one key prefix (docs/ROS2.md)."""

    detections: str  # geometry_msgs/msg/PointStamped in (daemon), out (thinkfast-detect)
    joint_states: str  # sensor_msgs/msg/JointState, measured (EGM feedback)
    joint_commands: str  # sensor_msgs/msg/JointState, commanded (each EGM reply)
    diagnostics: str  # diagnostic_msgs/msg/DiagnosticArray, the daemon's status


def topics(prefix: str) -> Topics:
    """The topics for key prefix ``prefix``: ``/<prefix>/detections``, ``/<prefix>/joint_states``,
    ``/<prefix>/joint_commands`` and the global ``/diagnostics``."""
    ns = namespace(prefix)
    return Topics(f"{ns}/detections", f"{ns}/joint_states", f"{ns}/joint_commands", "/diagnostics")


def dds_type_name(msgtype: str) -> str:
    """The DDS name of a ROS type: ``sensor_msgs/msg/JointState`` ->
    ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(msgtype: str) -> str:
    """REP-2016 type hash ``RIHS01_<64 hex>`` of ``msgtype`` (from its type description)."""
    if msgtype.startswith("vision_msgs/"):  # not in Jazzy's store: registered on first use
        return vision_typestore().hash_rihs01(msgtype)
    return typestore().hash_rihs01(msgtype)


def topic_key(domain: int, topic: str, msgtype: str) -> str:
    """rmw_zenoh's key expression of ``topic`` (fully qualified) carrying ``msgtype``:
    ``<domain>/<topic without leading slash>/<DDS type name>/<type hash>``."""
    name = topic.strip("/")
    return f"{check_domain(domain)}/{name}/{dds_type_name(msgtype)}/{type_hash(msgtype)}"


# ----------------------------------------------------------------------------- CDR codec
def ros_time(stamp: float):
    """``builtin_interfaces/msg/Time`` of ``stamp`` [s since the Unix epoch] (>= 0)."""
    if not math.isfinite(stamp) or stamp < 0.0:
        raise ValueError(f"stamp {stamp!r} is not a finite time >= 0")
    sec = math.floor(stamp)
    nanosec = round((stamp - sec) * 1e9)
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return typestore().types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nanosec))


def seconds(t) -> float:
    """Seconds [s since the Unix epoch] of a ``builtin_interfaces/msg/Time``."""
    return t.sec + t.nanosec * 1e-9


def header(stamp: float, frame_id: str):
    """``std_msgs/msg/Header`` at ``stamp`` [s since the Unix epoch] in ``frame_id``."""
    return typestore().types["std_msgs/msg/Header"](stamp=ros_time(stamp), frame_id=frame_id)


def decode_cdr(cdr: bytes, msgtype: str):
    """The rosbags message of type ``msgtype`` in ``cdr`` (raises :class:`RosDecodeError`)."""
    try:
        return typestore().deserialize_cdr(bytes(cdr), msgtype)
    except Exception as exc:  # rosbags raises several kinds on truncated or foreign bytes
        raise RosDecodeError(f"not a {msgtype} in CDR ({type(exc).__name__}: {exc})") from None


def encode_point_stamped(stamp: float, position, frame_id: str) -> bytes:
    """``geometry_msgs/msg/PointStamped`` in CDR: ``position`` [m] (3,) in ``frame_id`` at
    ``stamp`` [s since the Unix epoch]."""
    ts = typestore()
    x, y, z = (float(v) for v in position)
    point = ts.types["geometry_msgs/msg/Point"](x=x, y=y, z=z)
    msg = ts.types[POINT_STAMPED](header=header(stamp, frame_id), point=point)
    return bytes(ts.serialize_cdr(msg, POINT_STAMPED))


class StampedPoint(NamedTuple):
    """A decoded PointStamped: ``stamp`` [s since the Unix epoch], ``position`` [m] (3,),
    ``frame_id``."""

    stamp: float
    position: np.ndarray
    frame_id: str


def decode_point_stamped(cdr: bytes) -> StampedPoint:
    """Read a ``geometry_msgs/msg/PointStamped`` (raises :class:`RosDecodeError`)."""
    m = decode_cdr(cdr, POINT_STAMPED)
    pos = np.array([m.point.x, m.point.y, m.point.z], dtype=float)
    return StampedPoint(seconds(m.header.stamp), pos, m.header.frame_id)


def detection_from_point(cdr: bytes, seq: int | None = None) -> bytes:
    """The project's JSON detection (:mod:`thinkfast.contract.detection`) of a PointStamped:
    ``stamp`` from ``header.stamp``, ``position`` from ``point``, ``frame`` from
    ``header.frame_id`` (passed as is: the detection parser refuses any frame but ``camera`` and
    ``base``, counted ``bad_frame``), ``seq`` from the attachment's sequence number.

    Raises:
        RosDecodeError: ``cdr`` is not a PointStamped.
    """
    p = decode_point_stamped(cdr)
    if seq is not None and not 0 <= seq < 2**63:
        seq = None
    # a non-finite coordinate becomes a JSON literal that the parser refuses (bad_position)
    return encode_detection(p.stamp, p.position, p.frame_id, seq=seq)


def point_from_detection(payload: bytes) -> bytes | None:
    """The PointStamped of a JSON detection (``thinkfast-detect``'s output), or None when the
    payload is not a valid detection."""
    det = parse_detection(payload)
    if not isinstance(det, Detection):
        return None
    return encode_point_stamped(det.stamp, det.position, det.frame)


def encode_string(text: str) -> bytes:
    """``std_msgs/msg/String`` in CDR."""
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.types[STRING](data=text), STRING))


def encode_joint_state(stamp: float, position, velocity=None, names=JOINT_NAMES) -> bytes:
    """``sensor_msgs/msg/JointState`` in CDR: ``position`` [rad] (6,), ``velocity`` [rad/s] (6,)
    or None (left empty, as the message allows), no effort; ``frame_id`` ``base_link``."""
    ts = typestore()
    pos = np.asarray(position, dtype=np.float64).reshape(-1)
    vel = np.zeros(0) if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(-1)
    if len(pos) != len(names) or len(vel) not in (0, len(names)):
        raise ValueError(f"{len(names)} joints: got {len(pos)} positions, {len(vel)} velocities")
    msg = ts.types[JOINT_STATE](
        header=header(stamp, JOINT_FRAME),
        name=list(names),
        position=pos,
        velocity=vel,
        effort=np.zeros(0),
    )
    return bytes(ts.serialize_cdr(msg, JOINT_STATE))


class JointStateMsg(NamedTuple):
    """A decoded JointState (stamp [s], frame_id, names, position [rad], velocity [rad/s])."""

    stamp: float
    frame_id: str
    names: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray


def decode_joint_state(cdr: bytes) -> JointStateMsg:
    """Read a ``sensor_msgs/msg/JointState`` (raises :class:`RosDecodeError`)."""
    m = decode_cdr(cdr, JOINT_STATE)
    return JointStateMsg(
        seconds(m.header.stamp),
        m.header.frame_id,
        tuple(m.name),
        np.asarray(m.position, dtype=float),
        np.asarray(m.velocity, dtype=float),
    )
