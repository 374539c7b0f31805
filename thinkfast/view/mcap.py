"""A flight record as MCAP with ROS 2 messages, for Foxglove and the ROS 2 tools.

``thinkfast-sim record mcap RECORD -o OUT.mcap`` (and ``replay RECORD --mcap OUT.mcap``). Schemas
are ROS 2 message definitions (encoding ``ros2msg``), messages CDR (little endian, encoding
``cdr``), written with the ``mcap`` package (the ``view`` extra). Messages and schemas come
from the encoder of the live ROS 2 topics (:mod:`thinkfast.contract.ros`), so a recorded
JointState is the bytes the live topic carries. Channels:
:data:`thinkfast.view.ros_topics.TOPICS`; points in ``base`` [m], joints [rad]; the scene
(:mod:`thinkfast.view.scene`) is what the live Foxglove view draws.

The channel table and the scene: docs/RECORD_FORMAT.md, "MCAP export".
"""

from __future__ import annotations

import json
from pathlib import Path

from thinkfast.contract.ros import encode_string
from thinkfast.errors import ConfigError
from thinkfast.record.format import MODES, Record
from thinkfast.record.tables import (
    columns,
    event_times,
    plane_x,
    raw_positions,
    run_config,
)
from thinkfast.view.ros_topics import TOPICS, cdr_joint_state, cdr_point_stamped, schemas


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
        out.append((t, "/thinkfast/decisions", encode_string(json.dumps(obj))))
    for t, ev in zip(event_times(record), record.events, strict=True):
        text = json.dumps({"kind": ev.kind, "detail": ev.detail})
        out.append((t, "/thinkfast/events", encode_string(text)))
    out.sort(key=lambda m: m[0])
    return out


def write_mcap(
    record: Record, path: Path, joint_names, scene: tuple | None = None
) -> dict[str, int]:
    """Write ``record`` as MCAP to ``path`` (module doc); returns messages per topic.

    Args:
        scene: (robot, plane_x [m] or None, goal grid (G, 2) [m] or None) to add the
            ``/thinkfast/scene`` channel; None: the ROS 2 topics only.

    Raises:
        ConfigError: the ``mcap`` package is missing, or ``path`` cannot be written.
    """
    try:
        from mcap.writer import Writer
    except ImportError:
        raise ConfigError("--mcap", None, "needs mcap: pip install 'thinkfast[view]'") from None
    messages = record_messages(record, list(joint_names))
    specs = {t: (typ, "ros2msg", schemas()[typ].encode(), "cdr") for t, typ in TOPICS.items()}
    if scene is not None:
        from thinkfast.view.channels import channel_specs, scene_messages
        from thinkfast.view.scene import SCENE_TOPIC

        specs[SCENE_TOPIC] = channel_specs(status=False)[SCENE_TOPIC]
        messages = sorted(messages + scene_messages(record, *scene), key=lambda m: m[0])
    counts = dict.fromkeys(specs, 0)
    try:
        f = open(path, "wb")  # noqa: SIM115 (closed below, after the writer's finish)
    except OSError as exc:
        raise ConfigError("--mcap", None, f"cannot write {path}: {exc.strerror}") from None
    with f:
        w = Writer(f)
        w.start(profile="ros2", library="thinkfast")
        schema = {
            name: w.register_schema(name=name, encoding=enc, data=data)
            for name, enc, data, _ in sorted(set(specs.values()))
        }
        channel = {
            topic: w.register_channel(topic=topic, message_encoding=m_enc, schema_id=schema[name])
            for topic, (name, _, _, m_enc) in specs.items()
        }
        seq = dict.fromkeys(specs, 0)
        for t, topic, data in messages:
            ns = int(round(t * 1e9))
            w.add_message(channel[topic], log_time=ns, data=data, publish_time=ns,
                          sequence=seq[topic])  # fmt: skip
            seq[topic] += 1
            counts[topic] += 1
        w.finish()
    return counts
