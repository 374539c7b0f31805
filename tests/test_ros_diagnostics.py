"""The daemon's status as a DiagnosticArray: round trip through CDR, levels by state."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("rosbags")

from thinkfast.contract import ros_diagnostics  # noqa: E402
from thinkfast.contract.ros import RosDecodeError  # noqa: E402


def _round_trip(status):
    (d,) = ros_diagnostics.decode_diagnostics(ros_diagnostics.encode_diagnostics(status))
    return d


def test_diagnostics_round_trip_through_cdr():
    status = {"stamp": 1763800000.5, "state": "idle", "throws": 3, "braking": False,
              "detections": {"accepted": 10}, "egm_connected": True}  # fmt: skip
    d = _round_trip(status)
    assert (d.level, d.name, d.message) == (ros_diagnostics.LEVEL_OK, "thinkfast: daemon", "idle")
    assert d.values["state"] == "idle" and d.values["throws"] == "3"
    assert json.loads(d.values["detections"]) == {"accepted": 10}
    assert d.stamp == pytest.approx(1763800000.5)
    fault = {**status, "state": "fault", "braking": True, "brake_reason": "tracking"}
    assert _round_trip(fault).level == ros_diagnostics.LEVEL_ERROR
    lost = {**status, "egm_connected": False}
    assert _round_trip(lost).level == ros_diagnostics.LEVEL_WARN


@pytest.mark.parametrize(
    "status, level, message",
    [
        ({"state": "idle", "exiting": True}, 3, "idle: exiting"),
        ({"state": "tracking", "braking": True, "brake_reason": "signal"}, 1,
         "tracking: braking (signal)"),
        ({"state": "idle", "controller": {"standby": True}}, 1,
         "idle: controller standby (motors, EGM motion or RAPID stopped)"),
        ({"state": "tracking"}, 0, "tracking"),
    ],
)  # fmt: skip
def test_status_level_says_why_a_daemon_is_not_ok(status, level, message):
    assert ros_diagnostics.status_level(status) == (level, message)


def test_a_payload_that_is_no_diagnostic_array_is_refused():
    with pytest.raises(RosDecodeError, match="DiagnosticArray"):
        ros_diagnostics.decode_diagnostics(b"\x00\x01\x00\x00garbage")


def test_the_hardware_id_is_the_robot_the_daemon_runs():
    status = {"stamp": 1.0, "state": "idle", "robot": {"name": "abb_turned", "robot_toml": "x"}}
    (d,) = ros_diagnostics.decode_diagnostics(ros_diagnostics.encode_diagnostics(status))
    assert d.hardware_id == "abb_turned"
    (d,) = ros_diagnostics.decode_diagnostics(
        ros_diagnostics.encode_diagnostics({"stamp": 1.0, "state": "idle"})
    )
    assert d.hardware_id == ""  # a status naming no robot claims none
