"""docs/ROS2.md "Router mode": the daemon with examples/zenoh/ros2_peer.json5 (rmw_zenoh's
default session: a peer connecting to the router, multicast scouting off, gossip on) reaches a
ROS-like peer and a client that know only the router. The router is a real zenoh router
session on loopback standing in for rmw_zenohd; the daemon is the real process served by the
simulated EGM controller."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import zenoh

from tests.daemon_harness import DaemonRun
from thinkfast.contract import ros
from thinkfast.contract.zenoh_session import free_tcp_port

pytest.importorskip("rosbags")
ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.realtime


def _conf(name: str, router: str, tmp_path: Path) -> Path:
    """An example config with the router's endpoint in place of the documented one."""
    text = (ROOT / "examples/zenoh" / name).read_text()
    text = text.replace("tcp/localhost:7447", router).replace("tcp/ROS_HOST:7447", router)
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_daemon_reaches_ros_nodes_through_the_router(small_tree_015, robot, tmp_path):
    router_ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    rc = zenoh.Config()
    rc.insert_json5("mode", '"router"')
    rc.insert_json5("listen/endpoints", json.dumps([router_ep]))
    rc.insert_json5("scouting/multicast/enabled", "false")
    router = zenoh.open(rc)
    peer_conf = _conf("ros2_peer.json5", router_ep, tmp_path)
    run = DaemonRun(small_tree_015, tmp_path / "r.h5", q0=robot.home,
                    extra=("--ros-domain", "0", "--zenoh-config", str(peer_conf)))  # fmt: skip
    key = ros.topic_key(0, "/thinkfast/joint_states", ros.JOINT_STATE)
    sessions, got = [], {"peer": [], "client": []}
    try:
        client_conf = _conf("ros2_client.json5", router_ep, tmp_path)
        for name, conf in (("peer", peer_conf), ("client", client_conf)):
            s = zenoh.open(zenoh.Config.from_file(str(conf)))
            s.declare_subscriber(
                key, lambda sample, n=name: got[n].append(sample.payload.to_bytes())
            )
            sessions.append(s)
        deadline = time.time() + 20.0
        while time.time() < deadline and not (len(got["peer"]) > 10 and len(got["client"]) > 10):
            time.sleep(0.1)
    finally:
        for s in sessions:
            s.close()
        run.stop()
        router.close()
    for name in ("peer", "client"):
        assert len(got[name]) > 10, name
        msg = ros.decode_joint_state(got[name][-1])
        assert msg.frame_id == "base_link" and list(msg.names) == list(ros.JOINT_NAMES)
