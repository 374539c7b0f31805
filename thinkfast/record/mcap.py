"""A flight record as MCAP with ROS 2 messages, for Foxglove and the ROS 2 tools.

``thinkfast-sim record mcap RECORD -o OUT.mcap`` (and ``replay RECORD --mcap OUT.mcap``). Schemas
are ROS 2 message definitions (encoding ``ros2msg``), messages CDR (little endian, encoding
``cdr``), written with the ``mcap`` package (the ``view`` extra). The few message types used
are encoded here (:func:`cdr_joint_state`, ...); tests check the bytes against ``rosbags``.

Channels (:data:`TOPICS`; log and publish time = the record's Unix time):

| topic | type | from |
|---|---|---|
| ``/thinkfast/joints/commanded`` | sensor_msgs/msg/JointState | ``egm``: q_cmd, qd_cmd |
| ``/thinkfast/joints/measured`` | sensor_msgs/msg/JointState | ``egm``: q_fb |
| ``/thinkfast/detections/raw`` | geometry_msgs/msg/PointStamped | ``raw`` payloads, in base |
| ``/thinkfast/detections/accepted`` | geometry_msgs/msg/PointStamped | ``detections`` |
| ``/thinkfast/ball/belief`` | geometry_msgs/msg/PointStamped | ``beliefs``: mean position |
| ``/thinkfast/ball/crossing`` | geometry_msgs/msg/PointStamped | ``beliefs``: crossing point |
| ``/thinkfast/decisions`` | std_msgs/msg/String | ``decisions``, one JSON object |
| ``/thinkfast/events`` | std_msgs/msg/String | ``events``: {"kind", "detail"} |

Points are in the frame ``base`` (the robot base); joint states name the robot's joints.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from thinkfast.errors import ConfigError
from thinkfast.record.format import MODES, Record
from thinkfast.record.tables import (
    columns,
    event_times,
    plane_x,
    raw_positions,
    run_config,
)

FRAME = "base"
SEP = "=" * 80 + "\n"
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_POINT = "float64 x\nfloat64 y\nfloat64 z\n"
SCHEMAS = {
    "sensor_msgs/msg/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\n"
    "float64[] velocity\nfloat64[] effort\n"
    + SEP + "MSG: std_msgs/Header\n" + _HEADER
    + SEP + "MSG: builtin_interfaces/Time\n" + _TIME,
    "geometry_msgs/msg/PointStamped": "std_msgs/Header header\ngeometry_msgs/Point point\n"
    + SEP + "MSG: std_msgs/Header\n" + _HEADER
    + SEP + "MSG: builtin_interfaces/Time\n" + _TIME
    + SEP + "MSG: geometry_msgs/Point\n" + _POINT,
    "std_msgs/msg/String": "string data\n",
}  # fmt: skip
TOPICS = {
    "/thinkfast/joints/commanded": "sensor_msgs/msg/JointState",
    "/thinkfast/joints/measured": "sensor_msgs/msg/JointState",
    "/thinkfast/detections/raw": "geometry_msgs/msg/PointStamped",
    "/thinkfast/detections/accepted": "geometry_msgs/msg/PointStamped",
    "/thinkfast/ball/belief": "geometry_msgs/msg/PointStamped",
    "/thinkfast/ball/crossing": "geometry_msgs/msg/PointStamped",
    "/thinkfast/decisions": "std_msgs/msg/String",
    "/thinkfast/events": "std_msgs/msg/String",
}


# ------------------------------------------------------------------ CDR (little endian)
class _Cdr:
    """A CDR body after the 4-byte encapsulation header (alignment counts from the body)."""

    def __init__(self):
        self.buf = bytearray(b"\x00\x01\x00\x00")  # CDR_LE, options 0

    def _align(self, n: int) -> None:
        self.buf += b"\x00" * (-(len(self.buf) - 4) % n)

    def u32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<I", v)

    def i32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<i", v)

    def f64s(self, values) -> None:
        self._align(8)
        self.buf += np.asarray(values, dtype="<f8").tobytes()

    def string(self, s: str) -> None:
        data = s.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self.buf += data

    def header(self, t: float, frame: str) -> None:
        sec = int(np.floor(t))
        nsec = min(int(round((t - sec) * 1e9)), 999_999_999)
        self.i32(sec)
        self.u32(nsec)
        self.string(frame)


def cdr_joint_state(t: float, names, position, velocity=()) -> bytes:
    """sensor_msgs/msg/JointState at Unix time ``t`` [s]: positions [rad], velocities [rad/s]."""
    w = _Cdr()
    w.header(t, "")
    w.u32(len(names))
    for n in names:
        w.string(n)
    for values in (position, velocity, ()):
        w.u32(len(values))
        if len(values):
            w.f64s(values)
    return bytes(w.buf)


def cdr_point_stamped(t: float, p, frame: str = FRAME) -> bytes:
    """geometry_msgs/msg/PointStamped at Unix time ``t`` [s]: point (3,) [m] in ``frame``."""
    w = _Cdr()
    w.header(t, frame)
    w.f64s(np.asarray(p, dtype=float)[:3])
    return bytes(w.buf)


def cdr_string(text: str) -> bytes:
    """std_msgs/msg/String."""
    w = _Cdr()
    w.string(text)
    return bytes(w.buf)


# ------------------------------------------------------------------ the record's messages
def record_messages(record: Record, joint_names) -> list[tuple[float, str, bytes]]:
    """Every message of ``record``: (Unix time [s], topic, CDR bytes), sorted by time."""
    cfg = run_config(record)
    out: list[tuple[float, str, bytes]] = []
    e = columns(record, "egm")
    for i, t in enumerate(e["t"]):
        out.append(
            (t, "/thinkfast/joints/commanded",
             cdr_joint_state(t, joint_names, e["q_cmd"][i], e["qd_cmd"][i]))
        )  # fmt: skip
        out.append((t, "/thinkfast/joints/measured", cdr_joint_state(t, joint_names, e["q_fb"][i])))
    raw = raw_positions(record, cfg)
    for t, p in zip(raw.t, raw.position, strict=True):
        out.append((t, "/thinkfast/detections/raw", cdr_point_stamped(t, p)))
    d = columns(record, "detections")
    for i, t in enumerate(d["t_recv"]):
        p = (d["x"][i], d["y"][i], d["z"][i])
        out.append((t, "/thinkfast/detections/accepted", cdr_point_stamped(t, p)))
    b = columns(record, "beliefs")
    px = plane_x(record)
    for i, t in enumerate(b["t"]):
        out.append((t, "/thinkfast/ball/belief", cdr_point_stamped(t, b["mean"][i, :3])))
        if px is not None and b["crossing_ok"][i] > 0.5:
            p = (px, b["o_mean"][i, 0], b["o_mean"][i, 1])
            out.append((t, "/thinkfast/ball/crossing", cdr_point_stamped(t, p)))
    dec = columns(record, "decisions")
    for i, t in enumerate(dec["t"]):
        mode = int(dec["mode"][i])
        obj = {
            "mode": MODES[mode] if 0 <= mode < len(MODES) else None,
            "node": int(dec["node"][i]),
            "value": float(dec["value"][i]),
            "best_goal": int(dec["best_goal"][i]),
        }
        out.append((t, "/thinkfast/decisions", cdr_string(json.dumps(obj))))
    for t, ev in zip(event_times(record), record.events, strict=True):
        text = json.dumps({"kind": ev.kind, "detail": ev.detail})
        out.append((t, "/thinkfast/events", cdr_string(text)))
    out.sort(key=lambda m: m[0])
    return out


def write_mcap(record: Record, path: Path, joint_names) -> dict[str, int]:
    """Write ``record`` as MCAP to ``path`` (module doc); returns messages per topic.

    Raises:
        ConfigError: the ``mcap`` package is missing, or ``path`` cannot be written.
    """
    try:
        from mcap.writer import Writer
    except ImportError:
        raise ConfigError("--mcap", None, "needs mcap: pip install 'thinkfast[view]'") from None
    messages = record_messages(record, list(joint_names))
    counts = dict.fromkeys(TOPICS, 0)
    try:
        f = open(path, "wb")  # noqa: SIM115 (closed below, after the writer's finish)
    except OSError as exc:
        raise ConfigError("--mcap", None, f"cannot write {path}: {exc.strerror}") from None
    with f:
        w = Writer(f)
        w.start(profile="ros2", library="thinkfast")
        schema = {
            name: w.register_schema(name=name, encoding="ros2msg", data=text.encode())
            for name, text in SCHEMAS.items()
        }
        channel = {
            topic: w.register_channel(topic=topic, message_encoding="cdr", schema_id=schema[typ])
            for topic, typ in TOPICS.items()
        }
        seq = dict.fromkeys(TOPICS, 0)
        for t, topic, data in messages:
            ns = int(round(t * 1e9))
            w.add_message(channel[topic], log_time=ns, data=data, publish_time=ns,
                          sequence=seq[topic])  # fmt: skip
            seq[topic] += 1
            counts[topic] += 1
        w.finish()
    return counts
