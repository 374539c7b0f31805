"""ROS 2 over zenoh in rmw_zenoh's layout (docs/ROS2.md): CDR through rosbags, key expressions,
attachments and liveliness tokens on real zenoh sessions on loopback, and a throw blocked by the
real daemon driven only by PointStamped detections."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("rosbags")

from thinkfast.contract import ros, ros_diagnostics, ros_zenoh  # noqa: E402
from thinkfast.contract.detection import Detection, Rejection, parse_detection  # noqa: E402
from thinkfast.contract.zenoh_session import loopback_endpoint, open_peer  # noqa: E402

# REP-2016 type hashes. String's is the one rmw_zenoh's docs/design.md shows for `chatter`;
# JointState's is the one `ros2 topic info -v` prints on Jazzy; the others were computed by
# rosbags from the Jazzy definitions and are pinned so that a change cannot pass unnoticed.
STRING = "std_msgs/msg/String"
HASHES = {
    STRING: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    ros.POINT_STAMPED: "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897",
    ros.JOINT_STATE: "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    ros.DIAGNOSTIC_ARRAY: "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}
JOINT_STATES_KEY = (
    "0/thinkfast/joint_states/sensor_msgs::msg::dds_::JointState_/" + HASHES[ros.JOINT_STATE]
)
JOINT_COMMANDS_KEY = (
    "0/thinkfast/joint_commands/sensor_msgs::msg::dds_::JointState_/" + HASHES[ros.JOINT_STATE]
)
DETECTIONS_KEY = (
    "0/thinkfast/detections/geometry_msgs::msg::dds_::PointStamped_/" + HASHES[ros.POINT_STAMPED]
)
DIAGNOSTICS_KEY = (
    "0/diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_/" + HASHES[ros.DIAGNOSTIC_ARRAY]
)


# ----------------------------------------------------------------------------- names, hashes
@pytest.mark.parametrize("msgtype", sorted(HASHES))
def test_type_hashes_are_the_documented_ones(msgtype):
    assert ros.type_hash(msgtype) == HASHES[msgtype]


def test_key_expressions_follow_rmw_zenoh():
    # the example of rmw_zenoh's design document, then ours
    chatter = "0/chatter/std_msgs::msg::dds_::String_/" + HASHES[STRING]
    assert ros.topic_key(0, "/chatter", "std_msgs/msg/String") == chatter
    t = ros.topics("thinkfast")
    assert ros.topic_key(0, t.joint_states, ros.JOINT_STATE) == JOINT_STATES_KEY
    assert ros.topic_key(0, t.joint_commands, ros.JOINT_STATE) == JOINT_COMMANDS_KEY
    assert ros.topic_key(0, t.detections, ros.POINT_STAMPED) == DETECTIONS_KEY
    assert ros.topic_key(0, t.diagnostics, ros.DIAGNOSTIC_ARRAY) == DIAGNOSTICS_KEY
    assert ros.topic_key(7, "/a/b/", ros.JOINT_STATE).startswith("7/a/b/sensor_msgs::msg::dds_")
    assert ros.topics("cell/left").joint_states == "/cell/left/joint_states"


@pytest.mark.parametrize("domain", [-1, 233, 1.5, True, "0"])
def test_a_bad_domain_is_refused_naming_the_option(domain):
    with pytest.raises(ros.ConfigError, match="--ros-domain"):
        ros.check_domain(domain)


@pytest.mark.parametrize("prefix", ["thinkfast-1", "1abc", "a//b", "a b", ""])
def test_a_prefix_that_is_no_ros_namespace_is_refused(prefix):
    with pytest.raises(ros.ConfigError, match="--key-prefix"):
        ros.check_options(0, prefix)


@pytest.mark.parametrize(
    "prog, args, needle",
    [
        ("thinkfast-run", ("--tree", "missing.h5", "--ros-domain", "300"), "--ros-domain"),
        ("thinkfast-run", ("--tree", "m.h5", "--ros-domain", "0", "--key-prefix", "a-b"),
         "--key-prefix"),
        ("thinkfast-detect", ("--ros-domain", "-1"), "--ros-domain"),
    ],
)  # fmt: skip
def test_the_commands_refuse_bad_ros_options_in_one_line(prog, args, needle):
    from tests.conftest import assert_one_line_error, run_cli

    assert_one_line_error(run_cli(prog, *args, timeout=60), needle)


# ----------------------------------------------------------------------------- CDR round trips
def test_point_stamped_round_trip_through_cdr():
    cdr = ros.encode_point_stamped(1763800000.25, [6.91, -0.12, 1.43], "camera")
    assert cdr[:4] == b"\x00\x01\x00\x00"  # CDR little endian encapsulation
    raw = ros.typestore().deserialize_cdr(cdr, ros.POINT_STAMPED)
    assert (raw.header.stamp.sec, raw.header.stamp.nanosec) == (1763800000, 250_000_000)
    p = ros.decode_point_stamped(cdr)
    assert p.frame_id == "camera" and p.stamp == pytest.approx(1763800000.25, abs=1e-9)
    assert np.array_equal(p.position, [6.91, -0.12, 1.43])


def test_stamps_carry_into_seconds():
    t = ros.ros_time(12.9999999999)
    assert (t.sec, t.nanosec) == (13, 0)
    with pytest.raises(ValueError):
        ros.ros_time(-1.0)


def test_joint_state_round_trip_through_cdr():
    q, qd = np.linspace(-1.0, 1.0, 6), np.linspace(0.1, 0.6, 6)
    cdr = ros.encode_joint_state(1763800000.004, q, qd)
    m = ros.decode_joint_state(cdr)
    assert m.names == ("joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6")
    assert m.frame_id == "base_link"
    assert np.array_equal(m.position, q) and np.array_equal(m.velocity, qd)
    assert m.stamp == pytest.approx(1763800000.004, abs=1e-6)
    measured = ros.decode_joint_state(ros.encode_joint_state(1.0, q))
    assert measured.velocity.size == 0 and np.array_equal(measured.position, q)
    with pytest.raises(ValueError):
        ros.encode_joint_state(1.0, q[:5])


def test_undecodable_cdr_is_one_clear_error():
    for bad in (b"", b"\x00\x01\x00\x00\x01", b"{json}"):
        with pytest.raises(ros.RosDecodeError, match="PointStamped"):
            ros.decode_point_stamped(bad)


def test_point_stamped_becomes_the_projects_detection():
    cdr = ros.encode_point_stamped(1763800000.1234, [6.91, -0.12, 1.43], "base")
    det = parse_detection(ros.detection_from_point(cdr, seq=17))
    assert isinstance(det, Detection)
    assert (det.frame, det.seq) == ("base", 17)
    assert det.stamp == pytest.approx(1763800000.1234, abs=1e-9)
    assert np.array_equal(det.position, [6.91, -0.12, 1.43])
    # a frame the project does not know is refused like a JSON one
    optical = ros.encode_point_stamped(1.0, [0, 0, 5], "zed_left_camera_optical_frame")
    assert parse_detection(ros.detection_from_point(optical)) == Rejection(
        "bad_frame", "'zed_left_camera_optical_frame'"
    )
    nan = ros.encode_point_stamped(1.0, [np.nan, 0, 5], "camera")
    assert parse_detection(ros.detection_from_point(nan)).reason == "bad_position"
    # and back: thinkfast-detect's JSON output as a PointStamped
    back = ros.decode_point_stamped(ros.point_from_detection(ros.detection_from_point(cdr)))
    assert back.frame_id == "base" and np.array_equal(back.position, [6.91, -0.12, 1.43])
    assert ros.point_from_detection(b"not json") is None


# ----------------------------------------------------------------------------- real zenoh
@pytest.fixture
def two_peers():
    ep = loopback_endpoint()
    a = open_peer(listen=[ep])
    b = open_peer(connect=[ep])
    yield a, b
    b.close()
    a.close()


def _collect(session, key: str):
    got, lock = [], threading.Lock()

    def on_sample(s):
        att = s.attachment
        with lock:
            got.append((str(s.key_expr), s.payload.to_bytes(), att and att.to_bytes()))

    sub = session.declare_subscriber(key, on_sample)
    return got, sub


def _wait(cond, timeout=5.0):
    deadline = time.time() + timeout
    while time.time() < deadline and not cond():
        time.sleep(0.02)
    return cond()


@pytest.mark.parametrize(
    "topic, msgtype, key, cdr, check",
    [
        ("/thinkfast/joint_states", ros.JOINT_STATE, JOINT_STATES_KEY,
         ros.encode_joint_state(100.5, np.arange(6.0), -np.arange(6.0)),
         lambda b: np.array_equal(ros.decode_joint_state(b).velocity, -np.arange(6.0))),
        ("/thinkfast/detections", ros.POINT_STAMPED, DETECTIONS_KEY,
         ros.encode_point_stamped(100.5, [1, 2, 3], "camera"),
         lambda b: ros.decode_point_stamped(b).frame_id == "camera"),
        ("/diagnostics", ros.DIAGNOSTIC_ARRAY, DIAGNOSTICS_KEY,
         ros_diagnostics.encode_diagnostics({"stamp": 100.5, "state": "tracking"}),
         lambda b: ros_diagnostics.decode_diagnostics(b)[0].message == "tracking"),
    ],
    ids=["JointState", "PointStamped", "DiagnosticArray"],
)  # fmt: skip
def test_each_message_round_trips_through_zenoh_with_attachment(
    two_peers, topic, msgtype, key, cdr, check
):
    a, b = two_peers
    got, _sub = _collect(b, key)  # the documented key, written out: not derived by the code
    node = ros_zenoh.RosNode(a, 0, "test_node")
    pub = node.publisher(topic, msgtype)
    assert _wait(lambda: pub.pub.matching_status.matching, 30.0), "no route to the subscriber"
    t0 = time.time_ns()
    for _ in range(3):
        pub.put(cdr)
    assert _wait(lambda: len(got) == 3), got
    atts = [ros_zenoh.decode_attachment(att) for _, _, att in got]
    assert [x.seq for x in atts] == [1, 2, 3]
    assert all(abs(x.stamp_ns - t0) < 5e9 for x in atts)
    assert len({x.gid for x in atts}) == 1 and len(atts[0].gid) == 16
    assert all(k == key and payload == cdr and check(payload) for k, payload, _ in got)
    # the publisher is in the ROS graph: its liveliness token, seen from the other session
    tokens = [str(r.ok.key_expr) for r in b.liveliness().get("@ros2_lv/0/**") if r.ok]
    mp = [t for t in tokens if "/MP/" in t]
    assert len(mp) == 1 and any("/NN/%/%/test_node" in t for t in tokens)
    dds_and_hash = "/".join(key.split("/")[-2:])
    mangled = topic.replace("/", "%")
    assert mp[0].endswith(f"/MP/%/%/test_node/{mangled}/{dds_and_hash}/::,10:,:,:,,")
    node.close()


# ----------------------------------------------------------------------------- the daemon
class _RosSender:
    """What :func:`publish_throw` needs (``publish``), sending each detection as a CDR
    PointStamped on the ROS detections key (with rmw_zenoh's attachment)."""

    def __init__(self, session):
        self.node = ros_zenoh.RosNode(session, 0, "test_thrower")
        self.pub = self.node.publisher("/thinkfast/detections", ros.POINT_STAMPED)
        self.sent = 0

    def publish(self, payload: bytes) -> None:
        self.pub.put(ros.point_from_detection(payload))
        self.sent += 1


@pytest.mark.realtime
def test_a_throw_of_point_stamped_detections_is_blocked_like_a_json_one(
    small_tree_015, tmp_path, robot, kin
):
    """tests/test_daemon.py::test_a_throw_aimed_at_a_goal_is_blocked, the detections sent only
    as ROS 2 PointStamped; the ROS topics of the daemon are read on their documented keys."""
    from tests.daemon_harness import (
        DaemonRun,
        ballistic_throw,
        publish_throw,
        shield_distance_at_crossing,
    )
    from tests.test_daemon import BLOCK_RADIUS, _check_limits
    from thinkfast.sim.judge import judge
    from thinkfast.sim.throws import ThrowConfig, make_throw

    aim, flight, release = (0.25, 1.25), 0.8, (7.8, -0.2, 1.5)
    run = DaemonRun(
        small_tree_015, tmp_path / "rec.h5", "tree", q0=robot.home, extra=("--ros-domain", "0")
    )
    try:
        states, _s1 = _collect(run.session, JOINT_STATES_KEY)
        commands, _s2 = _collect(run.session, JOINT_COMMANDS_KEY)
        diagnostics, _s3 = _collect(run.session, DIAGNOSTICS_KEY)
        sender = _RosSender(run.session)
        routes = lambda: sender.pub.pub.matching_status.matching and states and commands  # noqa: E731
        assert _wait(lambda: routes() and diagnostics, timeout=20.0)  # all routes, no fixed wait
        t_release = time.time() + 0.8
        _, _, at = ballistic_throw(aim, flight, t_release, release)
        publish_throw(sender, at, t_release, flight)
        assert run.wait_state("idle", timeout=6.0), run.status[-1]
        time.sleep(0.2)
    finally:
        code, err = run.stop()
    assert code == 0, err
    rows = run.egm_rows()
    throw = make_throw(ThrowConfig(drag_coefficient=0.0), np.array(release), aim, flight, 0.0)
    verdict = judge(throw, rows[:, 0], rows[:, 2:8], kin, 0.8, 0.0335, t_release_wall=t_release)
    assert verdict.blocked, verdict
    dist, _ = shield_distance_at_crossing(rows, kin, t_release + flight, aim)
    assert dist < BLOCK_RADIUS  # the judge above decides the block
    assert max(s["throws"] for s in run.status) == 1
    _check_limits(rows, robot)
    assert np.allclose(rows[-1, 8:14], robot.home, atol=2e-3)
    # every PointStamped went through the intake, none through the JSON key
    last = [s for s in run.status if "ros" in s][-1]
    assert last["ros"] == {"domain": 0, "received": sender.sent, "undecodable": 0, "empty": 0}
    det = last["detections"]
    assert det["accepted"] + sum(det["dropped"].values()) == sender.sent
    assert det["accepted"] >= sender.sent - 2 and not any(det["rejected"].values())
    # the ROS topics: commanded and measured joints with every reply, diagnostics with status
    cmd = [ros.decode_joint_state(p) for _, p, _ in commands]
    meas = [ros.decode_joint_state(p) for _, p, _ in states]
    assert len(cmd) > 200 and abs(len(meas) - len(cmd)) <= 2
    assert all(m.names == ros.JOINT_NAMES and m.frame_id == "base_link" for m in cmd + meas)
    assert all(m.velocity.size == 6 for m in cmd) and all(m.velocity.size == 0 for m in meas)
    q_cmd = np.array([m.position for m in cmd])
    assert np.abs(q_cmd - robot.home).max() > 0.1  # it moved to block
    assert np.allclose(q_cmd[-1], robot.home, atol=2e-3)
    seqs = [ros_zenoh.decode_attachment(a).seq for _, _, a in commands]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # none lost on loopback
    diags = [ros_diagnostics.decode_diagnostics(p)[0] for _, p, _ in diagnostics]
    assert len(diags) > 10 and {d.name for d in diags} == {"thinkfast: daemon"}
    assert any(d.values["state"] == "executing" for d in diags)
    assert diags[-1].level == ros_diagnostics.LEVEL_STALE  # the exiting status


@pytest.mark.realtime
def test_the_detector_publishes_each_detection_as_a_point_stamped_too():
    from tests.test_perception_detector import F, H, W, _ball_depth, _disc_image
    from thinkfast.contract import keys
    from thinkfast.contract.zenoh_session import session_config
    from thinkfast.perception.config import DetectConfig
    from thinkfast.perception.frame import encode_frame
    from thinkfast.perception.node import DetectorNode

    c = np.array([3.0, 0.3, -0.2])  # the ball in camera [m]
    u, v = 639.5 - F * c[1] / c[0], 359.5 - F * c[2] / c[0]
    img = _disc_image(u, v, F * 0.0335 / 3.0)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([np.ones_like(xx), (639.5 - xx) / F, (359.5 - yy) / F], -1)
    xyz = (rays * _ball_depth(c)(xx, yy)[..., None]).astype(np.float32)
    ep = loopback_endpoint()
    node = DetectorNode(
        DetectConfig(), session_config(listen=[ep], multicast=False), "thinkfast", ros_domain=0
    )
    peer = open_peer(connect=[ep])
    try:
        js, _s1 = _collect(peer, keys.detections("thinkfast"))
        pts, _s2 = _collect(peer, DETECTIONS_KEY)
        time.sleep(0.3)
        frame = encode_frame(1e9, (F, F, 639.5, 359.5), img, xyz, seq=7)
        for _ in range(10):  # until the node has it (a route may take a moment to settle)
            peer.put(keys.camera_frame("thinkfast"), frame)
            if _wait(lambda: (node.step(), node.counters.frames["received"])[1], timeout=0.5):
                break
        assert node.counters.frames["received"] == 1, "the detector never got the frame"
        assert _wait(lambda: node.step() is not None and js and pts), (js, pts)
    finally:
        peer.close()
        node.close()
    det = parse_detection(js[0][1])
    p = ros.decode_point_stamped(pts[0][1])
    assert (p.frame_id, p.stamp) == (det.frame, det.stamp)
    assert np.allclose(p.position, det.position, atol=1e-12)
    assert np.allclose(p.position, c, atol=0.01)
    assert ros_zenoh.decode_attachment(pts[0][2]).seq == 1
