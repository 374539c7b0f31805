"""Record tools (thinkfast-sim record info|plot|mcap|view, replay --mcap/--rerun) on the flight
record of a real simulated throw (daemon process, EGM over UDP, zenoh, recorder)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import compile_small_tree
from thinkfast.contract.ros import JOINT_NAMES, decode_joint_state, encode_joint_state
from thinkfast.record.format import read_record
from thinkfast.sim.cli import main as sim_main
from thinkfast.view.ros_topics import TOPICS, cdr_joint_state, cdr_point_stamped, schemas


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(tree, record) of one real-time simulated throw at a real daemon with --record."""
    from thinkfast.control.config import RunConfig
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.realtime import run_with_daemon
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    d = tmp_path_factory.mktemp("record_tools")
    tree = compile_small_tree(d, depth=1, spacing=0.5)
    record = d / "run.h5"
    balls = sample_throws(ThrowConfig(), 1, seed=2)
    run_with_daemon(
        tree, "tree", load_robot(), balls, 2, RunConfig().camera, record=record,
        report=lambda s: None,
    )  # fmt: skip
    return tree, record


def _sim(*args: str) -> None:
    with pytest.raises(SystemExit) as exc:
        sim_main(list(args))
    assert exc.value.code == 0


def test_the_mcap_opens_with_ros2_schemas_and_the_expected_channels(recorded, tmp_path):
    from mcap.reader import make_reader

    _, record = recorded
    out = tmp_path / "run.mcap"
    _sim("record", "mcap", str(record), "-o", str(out))
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
        by_id = {s.id: s for s in summary.schemas.values()}
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == set(TOPICS)
        for topic, c in channels.items():
            s = by_id[c.schema_id]
            assert (s.name, s.encoding, c.message_encoding) == (TOPICS[topic], "ros2msg", "cdr")
            assert s.data.decode() == schemas()[s.name]
        counts = summary.statistics.channel_message_counts
        n = {c.topic: counts.get(c.id, 0) for c in summary.channels.values()}
        rec = read_record(record)
        assert (
            n["/thinkfast/joints/commanded"]
            == n["/thinkfast/joints/measured"]
            == len(rec.tables["egm"])
        )
        assert n["/thinkfast/detections/accepted"] == len(rec.tables["detections"]) > 10
        assert n["/thinkfast/decisions"] == len(rec.tables["decisions"]) > 0
        assert n["/thinkfast/events"] == len(rec.events) > 0
        first = next(m for _, c, m in reader.iter_messages(topics=["/thinkfast/joints/commanded"]))
        last_t = -np.inf
        for _, _, m in reader.iter_messages(log_time_order=False):
            assert m.log_time >= last_t  # written in time order
            last_t = m.log_time
    # the first commanded JointState decodes (rosbags, when installed) to the first EGM row
    rosbags = pytest.importorskip("rosbags.typesys")
    ts = rosbags.get_typestore(rosbags.Stores.ROS2_HUMBLE)
    msg = ts.deserialize_cdr(first.data, "sensor_msgs/msg/JointState")
    np.testing.assert_array_equal(msg.position, rec.tables["egm"][0, 8:14])
    np.testing.assert_array_equal(msg.velocity, rec.tables["egm"][0, 14:20])
    assert len(msg.name) == 6 and msg.name[0] == "joint_1"
    t = rec.tables["egm"][0, 0]
    assert abs(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - t) < 1e-6


def test_the_cdr_encoding_matches_rosbags():
    rosbags = pytest.importorskip("rosbags.typesys")
    ts = rosbags.get_typestore(rosbags.Stores.ROS2_HUMBLE)
    for typ, text in schemas().items():
        assert ts.generate_msgdef(typ, ros_version=2)[0] == text, typ
    T, H = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    JS, PS = ts.types["sensor_msgs/msg/JointState"], ts.types["geometry_msgs/msg/PointStamped"]
    P = ts.types["geometry_msgs/msg/Point"]
    q, qd = np.arange(6) * 0.1, np.arange(6) * -0.5
    names = [f"joint_{i}" for i in range(1, 7)]
    ref = JS(H(T(1700000000, 500000000), "base_link"), names, q, qd, np.zeros(0))
    ours = cdr_joint_state(1700000000.5, names, q, qd)
    assert ours == bytes(ts.serialize_cdr(ref, "sensor_msgs/msg/JointState"))
    ref = PS(H(T(12, 250000000), "base"), P(1.0, -2.0, 3.5))
    assert cdr_point_stamped(12.25, (1.0, -2.0, 3.5)) == bytes(
        ts.serialize_cdr(ref, "geometry_msgs/msg/PointStamped")
    )


def test_the_mcap_joint_states_are_the_live_topics_bytes(recorded, tmp_path):
    """One encoder for MCAP and the live ROS topics: same frame_id (base_link), same bytes."""
    from mcap.reader import make_reader

    _, record = recorded
    out = tmp_path / "run.mcap"
    _sim("record", "mcap", str(record), "-o", str(out))
    egm = read_record(record).tables["egm"]
    with open(out, "rb") as f:
        it = make_reader(f).iter_messages(topics=["/thinkfast/joints/commanded"])
        _, _, first = next(it)
    live = encode_joint_state(egm[0, 0], egm[0, 8:14], egm[0, 14:20], JOINT_NAMES)
    assert decode_joint_state(first.data).frame_id == decode_joint_state(live).frame_id
    assert decode_joint_state(first.data).frame_id == "base_link"
    assert first.data == live


def test_record_plot_writes_a_png_and_info_summarises(recorded, tmp_path, capsys):
    _, record = recorded
    png = tmp_path / "run.png"
    _sim("record", "plot", str(record), "-o", str(png))
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    _sim("record", "info", str(record))
    out = capsys.readouterr().out
    rec = read_record(record)
    assert f"egm {len(rec.tables['egm'])} rows" in out
    assert "throw_start 1" in out and "complete yes" in out


def test_replay_converts_to_rrd_with_the_goal_grid(recorded, tmp_path, capsys):
    import rerun as rr

    tree, record = recorded
    rrd, mcap = tmp_path / "run.rrd", tmp_path / "run.mcap"
    _sim("replay", str(record), "--rerun", f"save={rrd}", "--mcap", str(mcap), "--tree", str(tree))
    assert "replayed" not in capsys.readouterr().out  # no zenoh replay without --zenoh-connect
    rows: dict[str, int] = {}
    for c in rr.chunk.RrdReader(rrd).stream():
        rows[c.entity_path.lstrip("/")] = rows.get(c.entity_path.lstrip("/"), 0) + c.num_rows
    rec = read_record(record)
    expected = ("world/plane/goals", "world/plane/crossing", "world/ball/covariance",
                "world/arm/measured/shield", "joints/q_meas", "plan/value", "events")  # fmt: skip
    for entity in expected:
        assert rows.get(entity, 0) > 0, entity
    assert rows["world/detections/accepted"] == len(rec.tables["detections"])
    assert mcap.stat().st_size > 1000


def test_a_record_is_drawn_with_the_robot_it_was_flown_with(recorded, tmp_path):
    """The record names its robot and plane; a view finds that robot, and refuses another."""
    import dataclasses

    from thinkfast.errors import RobotModelError
    from thinkfast.record.format import read_record
    from thinkfast.record.tables import record_plane, run_config
    from thinkfast.view.replay import record_robot

    tree, path = recorded
    rec = read_record(path)
    assert rec.attrs["robot_name"] == "abb_irb1600_10_145"
    assert json.loads(rec.attrs["plane"])["distance"] == 0.8
    assert record_plane(rec) is None  # the contract's plane: estimates in base
    cfg = run_config(rec)
    assert record_robot(rec, cfg).toml_sha256 == rec.attrs["robot_toml_sha256"]
    assert record_robot(rec, cfg, tree).placement is not None  # the tree's, placed
    other = dataclasses.replace(rec, attrs={**rec.attrs, "robot_toml_sha256": "f" * 64})
    with pytest.raises(RobotModelError, match="flown with abb_irb1600_10_145 .robot.toml ffff"):
        record_robot(other, cfg)


def test_a_bad_record_is_one_error_naming_the_file(tmp_path):
    bad = tmp_path / "nope.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(SystemExit) as exc:
        sim_main(["record", "info", str(bad)])
    assert exc.value.code == 1


def test_json_of_decisions_is_valid(recorded):
    from thinkfast.view.mcap import record_messages

    _, record = recorded
    msgs = record_messages(read_record(record), [f"joint_{i}" for i in range(1, 7)])
    texts = [m for _, topic, m in msgs if topic == "/thinkfast/decisions"]
    obj = json.loads(texts[-1][8:-1].decode())  # CDR: header (4), length (4), text, NUL
    assert set(obj) == {"mode", "node", "value", "best_goal"}
    assert Path(record).exists()


def test_plot_steps_and_lines_stop_at_idle_gaps():
    """A decision holds until the next detection, not through a 5 s idle gap to the next throw;
    belief and crossing lines are not drawn across the gap."""
    from thinkfast.record.plot import decision_steps
    from thinkfast.record.tables import break_at_gaps

    executing = 2.0
    dec = {"t": np.array([10.0, 10.02, 10.04, 15.04, 15.06]),
           "value": np.array([0.5, 0.6, 0.7, 0.2, 0.3]),
           "mode": np.array([executing, executing, executing, 1.0, 1.0])}  # fmt: skip
    t, value, mode = decision_steps(dec, 10.0)
    held = mode[np.searchsorted(t, 2.5, side="right") - 1]  # the step in force 2.5 s in
    assert np.isnan(held)
    assert np.nanmax(t) < 5.1 and list(mode[~np.isnan(mode)]) == list(dec["mode"])
    tb, y = break_at_gaps(np.array([0.0, 0.02, 5.0, 5.02]), np.array([1.0, 1.0, 2.0, 2.0]), gap=0.5)
    assert len(tb) == 5 and np.isnan(y[2]) and 0.02 < tb[2] < 5.0
