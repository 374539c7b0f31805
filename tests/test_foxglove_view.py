"""``thinkfast-run --foxglove``: the real daemon serves the Foxglove WebSocket protocol; an
independent client (websocket-client, the protocol's JSON control messages and binary message
frames, protobuf decoded from the advertised schema) receives joints, detections and the scene."""

from __future__ import annotations

import base64
import json
import struct
import time

import numpy as np
import pytest

pytest.importorskip("foxglove")
websocket = pytest.importorskip("websocket")

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402

from tests.daemon_harness import DaemonRun  # noqa: E402
from thinkfast.contract.detection import encode_detection  # noqa: E402
from thinkfast.contract.zenoh_session import free_tcp_port  # noqa: E402
from thinkfast.daemon.foxglove_view import parse_hostport  # noqa: E402
from thinkfast.errors import ConfigError  # noqa: E402


def protobuf_class(channel: dict):
    """The message class of a protobuf channel from its advertised FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


@pytest.mark.realtime
def test_an_independent_client_receives_joints_detections_and_scene(
    small_tree_015, robot, tmp_path
):
    port = free_tcp_port()
    run = DaemonRun(small_tree_015, tmp_path / "r.h5", q0=robot.home,
                    extra=("--foxglove", f"127.0.0.1:{port}"))  # fmt: skip
    got: dict[str, list] = {"/thinkfast/joints": [], "/thinkfast/detections": [],
                            "/thinkfast/scene": []}  # fmt: skip
    try:
        ws = websocket.create_connection(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"],
                                         timeout=10)  # fmt: skip
        channels: dict[str, dict] = {}
        while len(channels) < 3:
            msg = json.loads(ws.recv())
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        subs = [{"id": i, "channelId": channels[t]["id"]} for i, t in enumerate(got)]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        topic_of = {i: t for i, t in enumerate(got)}
        time.sleep(0.3)
        for k in range(5):  # a ball held still in base: detections, belief, the ball's sphere
            run.publish(encode_detection(time.time() - 0.02, (5.0, 0.1, 1.2), "base", seq=k + 1))
            time.sleep(0.05)
        deadline = time.time() + 15.0
        while time.time() < deadline and not all(len(v) >= 3 for v in got.values()):
            data = ws.recv()
            if isinstance(data, bytes) and data[0] == 1:  # messageData
                sub, ts = struct.unpack_from("<IQ", data, 1)
                got[topic_of[sub]].append((ts, data[13:]))
        ws.close()
    finally:
        code, log = run.stop()
    assert code == 0, log
    assert channels["/thinkfast/joints"]["encoding"] == "json"
    joints = json.loads(got["/thinkfast/joints"][-1][1])
    np.testing.assert_allclose(joints["q_cmd"], robot.home, atol=1e-6)  # idle at home
    now = time.time()  # the stamps are Unix time (not time since boot): within a minute of now
    assert len(joints["q_meas"]) == 6 and abs(got["/thinkfast/joints"][-1][0] / 1e9 - now) < 60
    det = json.loads(got["/thinkfast/detections"][0][1])
    assert det["accepted"] and np.allclose(det["position"], (5.0, 0.1, 1.2))
    scene_cls = protobuf_class(channels["/thinkfast/scene"])
    ids = set()
    for _, payload in got["/thinkfast/scene"]:
        ids |= {e.id for e in scene_cls.FromString(payload).entities}
    assert "arm_commanded" in ids
    arm = next(e for _, p in got["/thinkfast/scene"] for e in scene_cls.FromString(p).entities
               if e.id == "arm_commanded")  # fmt: skip
    assert arm.frame_id == "base" and len(arm.lines[0].points) >= 7


def test_the_option_names_host_and_port():
    assert parse_hostport("8765") == ("127.0.0.1", 8765)
    assert parse_hostport("0.0.0.0:8766") == ("0.0.0.0", 8766)
    with pytest.raises(ConfigError, match="--foxglove"):
        parse_hostport("host:port")
