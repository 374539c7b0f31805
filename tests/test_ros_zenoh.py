"""rmw_zenoh's layout: liveliness tokens as its design document writes them, 33-byte
attachments, stable GIDs (the zenoh round trips: tests/test_ros.py)."""

from __future__ import annotations

import struct

import pytest

pytest.importorskip("rosbags")

from thinkfast.contract import ros, ros_zenoh  # noqa: E402


def test_liveliness_tokens_follow_rmw_zenoh():
    # rmw_zenoh's design document: the talker's publisher on chatter, and a node
    tok = ros_zenoh.entity_token(2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "/", "talker",
                           "/chatter", "std_msgs/msg/String")  # fmt: skip
    assert tok == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/" + ros.type_hash("std_msgs/msg/String") + "/::,10:,:,:,,"
    )
    node = ros_zenoh.node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener")
    assert node == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"


def test_attachment_is_rmw_zenohs_33_bytes():
    gid = bytes(range(16))
    data = ros_zenoh.encode_attachment(5, 1_763_800_000_123_456_789, gid)
    assert len(data) == 33
    assert data == struct.pack("<qq", 5, 1_763_800_000_123_456_789) + b"\x10" + gid
    assert ros_zenoh.decode_attachment(data) == ros_zenoh.Attachment(
        5, 1_763_800_000_123_456_789, gid
    )
    for bad in (None, b"", data[:-1], data[:16] + b"\x0f" + gid):
        with pytest.raises(ros.RosDecodeError):
            ros_zenoh.decode_attachment(bad)


def test_publisher_gids_are_stable_and_distinct_per_token():
    a = ros_zenoh.publisher_gid("@ros2_lv/0/z/0/1/MP/%/%/n/%a/T/H/q")
    b = ros_zenoh.publisher_gid("@ros2_lv/0/z/0/2/MP/%/%/n/%a/T/H/q")
    assert len(a) == ros_zenoh.GID_SIZE and a != b
    assert a == ros_zenoh.publisher_gid("@ros2_lv/0/z/0/1/MP/%/%/n/%a/T/H/q")
