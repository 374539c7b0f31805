"""The Foxglove channels (live view and MCAP): the painter's messages are the MCAP export's
ROS 2 bytes and the scene's protobuf; a record's MCAP carries the scene with the schema the live
server advertises (real foxglove-sdk, real mcap reader, the golden flight record)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")

from thinkfast.record.format import read_record  # noqa: E402
from thinkfast.record.tables import columns  # noqa: E402
from thinkfast.view.channels import (  # noqa: E402
    STATUS_TOPIC,
    ChannelPainter,
    channel_specs,
    scene_messages,
)
from thinkfast.view.ros_topics import TOPICS, cdr_joint_state, cdr_point_stamped  # noqa: E402
from thinkfast.view.scene import SCENE_TOPIC  # noqa: E402

GOLDEN = Path(__file__).parent / "data" / "record_v1_golden.h5"


def scene_class():
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    name, _, data, _ = channel_specs()[SCENE_TOPIC]
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def test_every_painter_call_is_messages_on_the_advertised_channels(robot):
    out: list = []
    p = ChannelPainter(lambda t, topic, d: out.append((t, topic, d)), robot, 0.8, None)
    q, qd = robot.home, np.linspace(-1, 1, 6)
    p.joints(10.0, q, qd, q + 0.01)
    p.raw(10.0, (3.0, 0.1, 1.2))
    p.belief(10.0, np.array([3.0, 0.1, 1.2, -9, 0, 2]), np.eye(6) * 1e-3)
    p.crossing(10.0, np.array([0.1, 1.2, 0.3]), np.eye(3) * 1e-3)
    p.decision(10.0, "executing: direct move to goal 3", 0.75, 3, None)
    p.arm(10.0, "commanded", q)
    p.status(10.0, {"state": "idle"})
    p.event(10.0, "brake", '{"reason": "signal"}')
    topics = [topic for _, topic, _ in out]
    assert set(topics) <= set(channel_specs()) and set(topics) >= set(TOPICS) - {
        "/thinkfast/detections/accepted"
    }
    by = {topic: d for _, topic, d in out}
    names = robot.joint_names
    assert by["/thinkfast/joints/commanded"] == cdr_joint_state(10.0, names, q, qd)  # the MCAP's
    assert by["/thinkfast/ball/crossing"] == cdr_point_stamped(10.0, (0.8, 0.1, 1.2))
    assert json.loads(by[STATUS_TOPIC]) == {"state": "idle"}
    ids = [
        e.id for _, t, d in out if t == SCENE_TOPIC for e in scene_class().FromString(d).entities
    ]
    assert ids == ["ball", "crossing", "plan", "arm_commanded"]  # no grid without goals


def test_a_records_mcap_carries_the_live_scene_schema_and_its_entities(robot, tmp_path):
    from mcap.reader import make_reader

    from thinkfast.view.mcap import write_mcap

    rec = read_record(GOLDEN)
    out = tmp_path / "g.mcap"
    goals = np.c_[np.linspace(-0.6, 0.6, 8), np.full(8, 1.2)]  # the record's best goal: 7
    counts = write_mcap(rec, out, robot.joint_names, (robot, 0.8, goals))
    assert counts[SCENE_TOPIC] > 0 and set(counts) == set(TOPICS) | {SCENE_TOPIC}
    name, enc, data, msg_enc = channel_specs()[SCENE_TOPIC]  # what the live server advertises
    with open(out, "rb") as f:
        reader = make_reader(f)
        entities: dict[str, object] = {}
        for schema, channel, msg in reader.iter_messages(topics=[SCENE_TOPIC]):
            assert (schema.name, schema.encoding, schema.data) == (name, enc, data)
            assert channel.message_encoding == msg_enc
            for e in scene_class().FromString(msg.data).entities:
                entities[e.id] = e
    assert {"arm_commanded", "arm_measured", "ball", "crossing", "plan", "goals"} <= set(entities)
    b = columns(rec, "beliefs")
    ball = entities["ball"].spheres[0].pose.position
    assert [ball.x, ball.y, ball.z] == pytest.approx(b["mean"][-1, :3].tolist())
    c = entities["crossing"].spheres[0].pose.position
    assert [c.x, c.y, c.z] == pytest.approx([0.8, *b["o_mean"][-1, :2]])
    assert entities["plan"].spheres[0].pose.position.y == pytest.approx(0.6)  # goal 7
    assert "value 0.625" in entities["plan"].texts[0].text


def test_scene_messages_come_in_time_order(robot):
    msgs = scene_messages(read_record(GOLDEN), robot, 0.8, None)
    t = [m[0] for m in msgs]
    assert t == sorted(t) and {m[1] for m in msgs} == {SCENE_TOPIC}
    # the arm twice per EGM row kept at 50 Hz (3 rows 4 ms apart: 1), belief, crossing, plan
    assert len(msgs) == 2 * 1 + 3


def test_the_scene_is_opt_in_and_the_default_mcap_still_opens_in_rosbags(tmp_path, capsys):
    """rosbags reads every MCAP schema as text: the protobuf scene is written on --scene only."""
    from mcap.reader import make_reader

    from thinkfast.sim.cli import main as sim_main

    plain, scene = tmp_path / "plain.mcap", tmp_path / "scene.mcap"
    for args in (["-o", str(plain)], ["-o", str(scene), "--scene"]):
        with pytest.raises(SystemExit) as exc:
            sim_main(["record", "mcap", str(GOLDEN), *args])
        assert exc.value.code == 0
    with open(scene, "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert SCENE_TOPIC in topics
    highlevel = pytest.importorskip("rosbags.highlevel")
    with highlevel.AnyReader([plain]) as reader:
        assert {c.topic for c in reader.connections} == set(TOPICS)
        c = next(c for c in reader.connections if c.topic == "/thinkfast/joints/commanded")
        _, _, raw = next(reader.messages(connections=[c]))
        msg = reader.deserialize(raw, c.msgtype)
    np.testing.assert_array_equal(msg.position, read_record(GOLDEN).tables["egm"][0, 8:14])
