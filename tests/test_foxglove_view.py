"""``thinkfast-run --foxglove``: the real daemon serves the Foxglove WebSocket protocol; an
independent client (tests/foxglove_client.py: websocket-client, the protocol's JSON control
messages and binary message frames, protobuf decoded from the advertised FileDescriptorSet, CDR
decoded from the advertised ROS 2 message definition) receives the scene of a simulated throw:
arm and shield, the ball's belief, the crossing Gaussian, the plan, the joints and the status."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websocket")

from tests.daemon_harness import DaemonRun, ballistic_throw, publish_throw  # noqa: E402
from tests.foxglove_client import listen, protobuf_class, ros2_decoder  # noqa: E402
from thinkfast.contract.zenoh_session import free_tcp_port  # noqa: E402
from thinkfast.errors import ConfigError  # noqa: E402
from thinkfast.view.foxglove import foxglove_address  # noqa: E402

AIM = (0.25, 1.25)  # y, z [m] on the plane where the simulated ball crosses


@pytest.mark.realtime
def test_an_independent_client_receives_the_scene_of_a_throw(small_tree_015, robot, tmp_path):
    port = free_tcp_port()
    run = DaemonRun(small_tree_015, tmp_path / "r.h5", q0=robot.home,
                    extra=("--foxglove", f"127.0.0.1:{port}"))  # fmt: skip
    result: dict = {}

    def throw_then_listen():
        import threading

        flight, t_release = 0.8, time.time() + 1.5
        result["t_cross"] = t_release + flight
        _, _, at = ballistic_throw(AIM, flight, t_release)
        th = threading.Thread(target=publish_throw, args=(run, at, t_release, flight), daemon=True)
        th.start()
        until = lambda got: _enough(got, result["t_cross"])  # noqa: E731
        result["ch"], result["got"] = listen(port, until, timeout=60.0)
        th.join(20)

    try:
        throw_then_listen()
        run.wait_state("idle", timeout=20.0)
    finally:
        code, log = run.stop()
    assert code == 0, log
    channels, got = result["ch"], result["got"]
    assert set(channels) >= {"/thinkfast/scene", "/thinkfast/status", "/thinkfast/ball/crossing",
                             "/thinkfast/joints/commanded", "/thinkfast/decisions"}  # fmt: skip

    # joints: CDR JointStates decoded by the advertised definition; idle at home at first
    joints = ros2_decoder(channels["/thinkfast/joints/commanded"])
    first = joints(got["/thinkfast/joints/commanded"][0][1])
    assert list(first.name) == [f"joint_{i}" for i in range(1, 7)]
    assert first.header.frame_id == "base_link"
    np.testing.assert_allclose(first.position, robot.home, atol=1e-6)
    assert got["/thinkfast/joints/commanded"][-1][0] / 1e9 > 1.7e9  # Unix time, not since boot

    # belief: the predicted crossing converges on where the simulated ball crosses (the last
    # prediction received before the ball reaches the plane)
    crossing = ros2_decoder(channels["/thinkfast/ball/crossing"])
    seen = [crossing(m) for _, m in got["/thinkfast/ball/crossing"]]
    stamp = lambda m: m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec  # noqa: E731
    before = [m for m in seen if stamp(m) < result["t_cross"] - 0.05]
    assert len(before) >= 5, [(stamp(m) - result["t_cross"], m.point) for m in seen]
    last = before[-1]
    plane_x = last.point.x
    assert abs(last.point.y - AIM[0]) < 0.1 and abs(last.point.z - AIM[1]) < 0.1, last.point
    assert last.header.frame_id == "base"

    # the scene: every entity of the Rerun view, decoded from the advertised protobuf schema
    scene_cls = protobuf_class(channels["/thinkfast/scene"])
    ents: dict[str, list] = {}  # id -> entities in the order received
    crossings = []  # (log time [s], entity)
    for ns, payload in got["/thinkfast/scene"]:
        for e in scene_cls.FromString(payload).entities:
            ents.setdefault(e.id, []).append(e)
            if e.id == "crossing":
                crossings.append((ns / 1e9, e))
    assert {"arm_commanded", "arm_measured", "ball", "crossing", "plan", "goals"} <= set(ents)
    arm = ents["arm_commanded"][-1]
    assert arm.frame_id == "base" and len(arm.lines[0].points) >= 7
    shield = arm.cylinders[0]  # the shield disk at the tool, its diameter the robot's
    assert shield.size.x == pytest.approx(2 * robot.shield_radius)
    cross = [e for t, e in crossings if t < result["t_cross"] - 0.05][-1].spheres[0]
    assert cross.pose.position.x == pytest.approx(plane_x)
    assert abs(cross.pose.position.y - AIM[0]) < 0.1 and abs(cross.pose.position.z - AIM[1]) < 0.1
    assert 0 < cross.size.y < 0.5 and 0 < cross.size.z < 0.5  # 2-sigma ellipse, not degenerate
    ball = ents["ball"][-1]
    assert len(ball.spheres) == 2 and len(ball.arrows) == 1  # mean, covariance, velocity
    assert ball.arrows[0].shaft_length > 0.1  # a ball in flight (m/s x 0.08 s)
    plans = [e for e in ents["plan"] if e.lines]
    assert plans, "no plan with a shield path"
    path = np.array([[p.x, p.y, p.z] for p in plans[-1].lines[0].points])
    assert len(path) >= 2 and np.all(np.linalg.norm(path, axis=1) < 2.5)  # within the arm's reach
    assert plans[-1].texts[0].text

    # status: the daemon's message, JSON
    status = json.loads(got["/thinkfast/status"][-1][1])
    assert status["state"] in ("idle", "executing", "confirming", "tracking", "returning")
    assert status["view"]["errors"] == 0 and status["view"]["done"] > 0


def _enough(got: dict, t_cross: float) -> bool:
    """Every channel the test reads has spoken, and the view (which may lag on a loaded host:
    it waits for time in the EGM cycle) has drawn the detections up to the ball's crossing at
    ``t_cross`` [s] (a detection's steps run in order: its crossing after its point)."""
    need = ("/thinkfast/joints/commanded", "/thinkfast/status", "/thinkfast/scene",
            "/thinkfast/decisions")  # fmt: skip
    if not all(got.get(t) for t in need):
        return False
    accepted = got.get("/thinkfast/detections/accepted", ())
    return bool(accepted) and accepted[-1][0] / 1e9 > t_cross - 0.03


def test_the_option_names_host_and_port():
    assert foxglove_address("8765") == ("127.0.0.1", 8765)
    assert foxglove_address("0.0.0.0:8766") == ("0.0.0.0", 8766)
    assert foxglove_address("[::1]:8767") == ("::1", 8767)
    assert foxglove_address(":8765") == ("127.0.0.1", 8765)
    for bad in ("host:port", "99999", "", "[::1]8765"):
        with pytest.raises(ConfigError, match="--foxglove"):
            foxglove_address(bad)
