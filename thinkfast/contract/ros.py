"""ROS 2 messages on zenoh, laid out as ``rmw_zenoh`` lays them out (docs/ROS2.md).

A ROS 2 node that runs ``rmw_zenoh_cpp`` (Jazzy, Kilted) and reaches our zenoh session (through
the same zenoh router) sees the topics published here, and its publishers reach our subscribers,
without ROS installed on our side:

* **key expression** of a topic: ``<domain_id>/<fully qualified name without the leading
  slash>/<DDS type name>/<type hash>``, e.g.
  ``0/thinkfast/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e...``;
* **payload**: the message in CDR (XCDR1, little endian, with the 4-byte encapsulation header);
  written and read by ``rosbags`` (:func:`typestore`), never by hand;
* **attachment** of every sample, 33 bytes in zenoh's own serialisation: sequence number (int64
  little endian, 1 for a publisher's first sample), source timestamp (int64 little endian, ns
  since the Unix epoch), and the publisher's 16-byte GID (one LEB128 length byte, 16, then the
  bytes); :func:`encode_attachment`;
* **liveliness tokens** ``@ros2_lv/...`` for the node and each publisher and subscription
  (:class:`RosNode`), so that ``ros2 node list`` / ``ros2 topic list`` / ``ros2 topic echo``
  find them.

The type hash is REP-2016's ``RIHS01_<sha256 of the type description>``, computed by rosbags
from the message definitions of its ROS 2 Jazzy store (the tests pin the values, and the one of
``std_msgs/msg/String`` to the example of rmw_zenoh's design document).

Frames and units (REP-103/105): a ``geometry_msgs/msg/PointStamped`` detection carries the ball
centre [m] in ``header.frame_id`` = ``camera`` or ``base`` (the project's frames,
docs/INTERFACES.md: both x forward, y left, z up; not a ``*_optical_frame``), stamped with the
capture time. ``sensor_msgs/msg/JointState`` names the joints ``joint_1`` .. ``joint_6`` (the
URDF's) with ``frame_id`` ``base_link``, positions [rad] and velocities [rad/s].

``rosbags`` is the optional extra ``ros`` (``pip install 'thinkfast[ros]'``); without it, using
this module raises a :class:`ConfigError` that says so.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import re
import struct
import time
from typing import Any, NamedTuple

import numpy as np

from thinkfast.contract.detection import Detection, encode_detection, parse_detection
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
GID_SIZE = 16  # RMW_GID_STORAGE_SIZE
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
# QoS part of a liveliness token (rmw_zenoh's compact form): the defaults (reliable, volatile,
# keep last) with depth 10, as rmw_zenoh writes it for a default profile of depth 10
QOS_TOKEN = "::,10:,:,:,,"
_NAME_TOKEN = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


class RosDecodeError(ThinkfastError):
    """A payload is not the CDR of the message type expected, or an attachment is not
    rmw_zenoh's. The message says which."""


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
        from thinkfast.contract.ros_vision import vision_typestore

        return vision_typestore().hash_rihs01(msgtype)
    return typestore().hash_rihs01(msgtype)


def topic_key(domain: int, topic: str, msgtype: str) -> str:
    """rmw_zenoh's key expression of ``topic`` (fully qualified) carrying ``msgtype``:
    ``<domain>/<topic without leading slash>/<DDS type name>/<type hash>``."""
    name = topic.strip("/")
    return f"{check_domain(domain)}/{name}/{dds_type_name(msgtype)}/{type_hash(msgtype)}"


def _mangle(name: str) -> str:
    """A name inside a liveliness token: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def node_token(domain: int, zid: str, node_id: int, ns: str, node: str) -> str:
    """Liveliness key of a node (entity kind ``NN``; enclave unset)."""
    return f"@ros2_lv/{domain}/{zid}/{node_id}/{node_id}/NN/%/{_mangle(ns)}/{node}"


def entity_token(
    domain: int, zid: str, node_id: int, entity_id: int, kind: str, ns: str, node: str,
    topic: str, msgtype: str,
) -> str:  # fmt: skip
    """Liveliness key of a publisher (``kind`` ``MP``) or subscription (``MS``) of ``topic``."""
    return (
        f"@ros2_lv/{domain}/{zid}/{node_id}/{entity_id}/{kind}/%/{_mangle(ns)}/{node}/"
        f"{_mangle(topic)}/{dds_type_name(msgtype)}/{type_hash(msgtype)}/{QOS_TOKEN}"
    )


# ----------------------------------------------------------------------------- attachment
class Attachment(NamedTuple):
    """What rmw_zenoh attaches to a sample: ``seq`` (a publisher's counter, from 1), ``stamp_ns``
    (source time [ns since the Unix epoch]) and the publisher's ``gid`` (16 bytes)."""

    seq: int
    stamp_ns: int
    gid: bytes


def encode_attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment, written by zenoh's serialiser (``zenoh.ext.z_serialize``: two
    int64 little endian, then the GID as a sequence: LEB128 length 16 and the bytes)."""
    import zenoh.ext as zx

    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return zx.z_serialize((zx.Int64(seq), zx.Int64(stamp_ns), bytes(gid))).to_bytes()


def decode_attachment(data: bytes | None) -> Attachment:
    """Read an attachment written by :func:`encode_attachment` (or by rmw_zenoh).

    Raises:
        RosDecodeError: missing, or not 33 bytes of that layout.
    """
    if data is None:
        raise RosDecodeError("the sample has no attachment (rmw_zenoh always sends one)")
    data = bytes(data)
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        raise RosDecodeError(f"attachment of {len(data)} bytes is not rmw_zenoh's (33)")
    seq, stamp_ns = struct.unpack_from("<qq", data)
    return Attachment(seq, stamp_ns, data[17:])


def publisher_gid(token: str) -> bytes:
    """A stable 16-byte GID for the entity of liveliness key ``token`` (the first 16 bytes of its
    SHA-256; rmw_zenoh takes an XXH3-128 of the same key, the value only has to be unique)."""
    return hashlib.sha256(token.encode()).digest()[:GID_SIZE]


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


def _seconds(t) -> float:
    return t.sec + t.nanosec * 1e-9


def _header(stamp: float, frame_id: str):
    return typestore().types["std_msgs/msg/Header"](stamp=ros_time(stamp), frame_id=frame_id)


def _decode(cdr: bytes, msgtype: str):
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
    msg = ts.types[POINT_STAMPED](header=_header(stamp, frame_id), point=point)
    return bytes(ts.serialize_cdr(msg, POINT_STAMPED))


class StampedPoint(NamedTuple):
    """A decoded PointStamped: ``stamp`` [s since the Unix epoch], ``position`` [m] (3,),
    ``frame_id``."""

    stamp: float
    position: np.ndarray
    frame_id: str


def decode_point_stamped(cdr: bytes) -> StampedPoint:
    """Read a ``geometry_msgs/msg/PointStamped`` (raises :class:`RosDecodeError`)."""
    m = _decode(cdr, POINT_STAMPED)
    pos = np.array([m.point.x, m.point.y, m.point.z], dtype=float)
    return StampedPoint(_seconds(m.header.stamp), pos, m.header.frame_id)


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
        header=_header(stamp, JOINT_FRAME),
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
    m = _decode(cdr, JOINT_STATE)
    return JointStateMsg(
        _seconds(m.header.stamp),
        m.header.frame_id,
        tuple(m.name),
        np.asarray(m.position, dtype=float),
        np.asarray(m.velocity, dtype=float),
    )


# DiagnosticStatus levels (diagnostic_msgs/msg/DiagnosticStatus: OK 0, WARN 1, ERROR 2, STALE 3)
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR, LEVEL_STALE = 0, 1, 2, 3
DIAG_NAME = "thinkfast: daemon"
DIAG_HARDWARE = "abb_irb1600"


def status_level(status: dict) -> tuple[int, str]:
    """Diagnostic level and message of a daemon status: ERROR in ``fault``, WARN while braking,
    while the controller is not talking, or while it does not follow (standby); else OK. The
    message is the state, and why when it is not OK."""
    state = str(status.get("state"))
    if status.get("exiting"):
        return LEVEL_STALE, f"{state}: exiting"
    if state == "fault":
        return LEVEL_ERROR, f"fault: {status.get('brake_reason')}"
    if status.get("braking"):
        return LEVEL_WARN, f"{state}: braking ({status.get('brake_reason')})"
    if not status.get("egm_connected", True):
        return LEVEL_WARN, f"{state}: no EGM controller"
    if (status.get("controller") or {}).get("standby"):
        return LEVEL_WARN, f"{state}: controller standby (motors, EGM motion or RAPID stopped)"
    return LEVEL_OK, state


def _value_text(v: Any) -> str:
    return v if isinstance(v, str) else json.dumps(v, separators=(",", ":"))


def encode_diagnostics(status: dict) -> bytes:
    """``diagnostic_msgs/msg/DiagnosticArray`` in CDR of one daemon status (stamp from
    ``status['stamp']``): one DiagnosticStatus named ``thinkfast: daemon`` whose level and
    message come from :func:`status_level` and whose values are the status's keys (strings as
    they are, everything else as compact JSON)."""
    ts = typestore()
    T = ts.types
    level, message = status_level(status)
    values = [
        T["diagnostic_msgs/msg/KeyValue"](key=str(k), value=_value_text(v))
        for k, v in status.items()
    ]
    st = T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level, name=DIAG_NAME, message=message, hardware_id=DIAG_HARDWARE, values=values
    )
    msg = T[DIAGNOSTIC_ARRAY](header=_header(float(status["stamp"]), ""), status=[st])
    return bytes(ts.serialize_cdr(msg, DIAGNOSTIC_ARRAY))


class DiagnosticMsg(NamedTuple):
    """One decoded DiagnosticStatus of a DiagnosticArray (with the array's stamp [s])."""

    stamp: float
    level: int
    name: str
    message: str
    hardware_id: str
    values: dict[str, str]


def decode_diagnostics(cdr: bytes) -> list[DiagnosticMsg]:
    """Read a ``diagnostic_msgs/msg/DiagnosticArray`` (raises :class:`RosDecodeError`)."""
    m = _decode(cdr, DIAGNOSTIC_ARRAY)
    stamp = _seconds(m.header.stamp)
    return [
        DiagnosticMsg(
            stamp, int(s.level), s.name, s.message, s.hardware_id,
            {kv.key: kv.value for kv in s.values},
        )
        for s in m.status
    ]  # fmt: skip


# ----------------------------------------------------------------------------- zenoh entities
class RosPublisher:
    """A ROS 2 publisher on a zenoh session: rmw_zenoh's key, attachment and liveliness token.

    Args:
        session: an open zenoh session.
        key: the topic's key expression (:func:`topic_key`).
        token: the publisher's liveliness key (:func:`entity_token`).
    """

    def __init__(self, session, key: str, token: str):
        self.key = key
        self.pub = session.declare_publisher(key)
        self.token = session.liveliness().declare_token(token)
        self.gid = publisher_gid(token)
        self.seq = 1

    def put(self, cdr: bytes) -> None:
        """Publish one CDR payload with the next sequence number and the time now."""
        self.pub.put(cdr, attachment=encode_attachment(self.seq, time.time_ns(), self.gid))
        self.seq += 1

    def close(self) -> None:
        for e in (self.token, self.pub):
            try:
                e.undeclare()
            except Exception:  # already gone with the session
                pass


class RosNode:
    """A ROS 2 node made of zenoh entities: its liveliness token, and publishers and
    subscriptions declared with theirs (what ``ros2 node list`` / ``ros2 topic list`` read).

    Args:
        session: an open zenoh session (one node per session here).
        domain: ROS domain id.
        name: node name (``thinkfast_run``, ``thinkfast_detect``).
        ns: node namespace (``/`` for none).
    """

    def __init__(self, session, domain: int, name: str, ns: str = "/"):
        self.session, self.domain, self.name, self.ns = session, check_domain(domain), name, ns
        self.zid = str(session.info.zid())
        self.node_id = 0
        self._next_id = 1
        self.token = session.liveliness().declare_token(
            node_token(self.domain, self.zid, self.node_id, ns, name)
        )
        self._entities: list = []

    def _token(self, kind: str, topic: str, msgtype: str) -> str:
        eid, self._next_id = self._next_id, self._next_id + 1
        return entity_token(
            self.domain, self.zid, self.node_id, eid, kind, self.ns, self.name, topic, msgtype
        )

    def publisher(self, topic: str, msgtype: str) -> RosPublisher:
        """A publisher of ``msgtype`` on ``topic`` (fully qualified)."""
        pub = RosPublisher(
            self.session, topic_key(self.domain, topic, msgtype), self._token("MP", topic, msgtype)
        )
        self._entities.append(pub)
        return pub

    def subscriber(self, topic: str, msgtype: str, handler):
        """A zenoh subscriber of ``msgtype`` on ``topic`` with ``handler`` (a callback or a
        zenoh channel), announced as a ROS subscription."""
        sub = self.session.declare_subscriber(topic_key(self.domain, topic, msgtype), handler)
        token = self.session.liveliness().declare_token(self._token("MS", topic, msgtype))
        self._entities += [sub, token]
        return sub

    def close(self) -> None:
        """Undeclare every entity and the node's token (before the session closes)."""
        for e in [*self._entities, self.token]:
            try:
                e.close() if isinstance(e, RosPublisher) else e.undeclare()
            except Exception:
                pass
        self._entities.clear()
