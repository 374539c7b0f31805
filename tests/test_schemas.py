"""docs/schemas: the payloads the code really publishes validate; malformed ones do not."""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import zenoh

from tests.daemon_harness import DaemonRun, ballistic_throw, publish_throw
from tests.test_perception_detector import F as FOCAL
from tests.test_perception_detector import _ball_depth, _disc_image, _frame
from thinkfast.contract.detection import Detection, parse_detection
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.perception.config import DetectConfig
from thinkfast.perception.detect import detect
from thinkfast.perception.detect import detection_payload as detector_payload
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.camera import detection_payload as sim_payload
from thinkfast.sim.throws import ThrowConfig, sample_throws

SCHEMAS = Path(__file__).resolve().parents[1] / "docs" / "schemas"


def _validator(name: str):
    schema = json.loads((SCHEMAS / f"{name}.schema.json").read_text())
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def _valid(name: str, obj) -> bool:
    return _validator(name).is_valid(obj)


@pytest.fixture(scope="module")
def sim_detections() -> list[dict]:
    throw = sample_throws(ThrowConfig(), 1, seed=3)[0]
    sds = observe(throw, CameraModelConfig(), CameraExtrinsic(), np.random.default_rng(3), 1.7e9)
    assert len(sds) > 10
    return [json.loads(sim_payload(sd, with_covariance=i % 2 == 1)) for i, sd in enumerate(sds)]


def test_the_simulated_cameras_payloads_validate(sim_detections):
    v = _validator("detection")
    for obj in sim_detections:
        v.validate(obj)
    assert any("covariance" in o for o in sim_detections)


def test_the_detectors_payloads_validate_in_both_frames():
    c = np.array([3.0, 0.3, -0.2])
    u, v = 639.5 - FOCAL * c[1] / c[0], 359.5 - FOCAL * c[2] / c[0]
    frame = _frame(_disc_image(u, v, FOCAL * 0.0335 / 3.0), _ball_depth(c))
    found = detect(frame, DetectConfig())
    ext = CameraExtrinsic(xyz=(0.5, -0.1, 0.3), rpy=(0.0, 0.1, 0.2))
    for payload in (
        detector_payload(found, frame.stamp, frame.seq),
        detector_payload(found, frame.stamp, None, "base", ext.rotation(), ext.translation()),
    ):
        _validator("detection").validate(json.loads(payload))


BAD_DETECTIONS = [
    ("no stamp", lambda o: o.pop("stamp")),
    ("no position", lambda o: o.pop("position")),
    ("two coordinates", lambda o: o.update(position=[1.0, 2.0])),
    ("string coordinate", lambda o: o.update(position=[1.0, "2", 3.0])),
    ("negative stamp", lambda o: o.update(stamp=-1.0)),
    ("stamp as text", lambda o: o.update(stamp="1763800000.1")),
    ("unknown frame", lambda o: o.update(frame="world")),
    ("confidence above 1", lambda o: o.update(confidence=1.5)),
    ("fractional seq", lambda o: o.update(seq=1.5)),
    ("boolean seq", lambda o: o.update(seq=True)),
    ("negative seq", lambda o: o.update(seq=-1)),
    ("seq beyond int64", lambda o: o.update(seq=2**63)),
    ("covariance of 6", lambda o: o.update(covariance=[0.0] * 6)),
]
# the daemon reads no `camera` key yet (one camera, one extrinsic): only the schema refuses these
SCHEMA_ONLY = [("camera as number", lambda o: o.update(camera=2))]


@pytest.mark.parametrize("what, breaks", BAD_DETECTIONS, ids=[b[0] for b in BAD_DETECTIONS])
def test_malformed_detections_fail_the_schema_and_the_daemon_refuses_them(
    sim_detections, what, breaks
):
    obj = copy.deepcopy(sim_detections[0])
    breaks(obj)
    assert not _valid("detection", obj), what
    assert not isinstance(parse_detection(json.dumps(obj).encode()), Detection), what


@pytest.mark.parametrize("what, breaks", SCHEMA_ONLY, ids=[b[0] for b in SCHEMA_ONLY])
def test_malformed_optional_keys_the_daemon_ignores_fail_the_schema(sim_detections, what, breaks):
    obj = copy.deepcopy(sim_detections[0])
    breaks(obj)
    assert not _valid("detection", obj), what


def test_what_the_schema_accepts_the_daemon_accepts(sim_detections):
    extra = dict(sim_detections[0], frame=None, seq=None, confidence=None, future_key=[1])
    for obj in (sim_detections[0], extra, {"stamp": 1.0, "position": [1, 2, 3]}):
        assert _valid("detection", obj)
        assert isinstance(parse_detection(json.dumps(obj).encode()), Detection)


@pytest.mark.realtime
def test_the_detector_status_validates(tmp_path):
    from thinkfast.contract import keys
    from thinkfast.contract.zenoh_session import free_tcp_port, session_config
    from thinkfast.perception.node import DetectorNode

    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    node = DetectorNode(DetectConfig(), session_config(listen=[ep], multicast=False), "tfs")
    listener = zenoh.open(session_config(connect=[ep], multicast=False))
    got: list[dict] = []
    sub = listener.declare_subscriber(
        keys.detector_status("tfs"), lambda s: got.append(s.payload.to_bytes())
    )
    try:
        deadline = time.monotonic() + 10
        while not got and time.monotonic() < deadline:
            node.publish_status(time.time())
            time.sleep(0.1)
    finally:
        sub.undeclare()
        listener.close()
        node.close()
    assert got
    obj = json.loads(got[0])
    _validator("detector_status").validate(obj)
    assert not _valid("detector_status", {**obj, "published": -1})


@pytest.fixture(scope="module")
def daemon_messages(small_tree_015, robot, tmp_path_factory):
    """Status and setpoint messages of the real daemon through one throw (idle, tracking,
    executing, returning) on loopback."""
    run = DaemonRun(small_tree_015, tmp_path_factory.mktemp("rec") / "r.h5", q0=robot.home)
    try:
        t_release = time.time() + 0.5
        _, _, at = ballistic_throw((0.25, 1.25), 0.8, t_release, (7.8, -0.2, 1.5))
        publish_throw(run, at, t_release, 0.8)
        run.wait_state("idle", 8.0)
        time.sleep(0.3)
    finally:
        run.stop()
    return list(run.status), list(run.setpoints)


@pytest.mark.realtime
def test_the_daemons_status_validates_in_every_state_it_passed(daemon_messages):
    status, _ = daemon_messages
    v = _validator("status")
    for obj in status:
        v.validate(obj)
    assert {"idle", "executing"} <= {s["state"] for s in status}


@pytest.mark.realtime
def test_the_daemons_setpoints_validate(daemon_messages):
    _, setpoints = daemon_messages
    v = _validator("setpoint")
    for obj in setpoints[:: max(1, len(setpoints) // 500)]:
        v.validate(obj)
    assert len(setpoints) > 100


@pytest.mark.realtime
@pytest.mark.parametrize(
    "breaks",
    [
        lambda o: o.pop("state"),
        lambda o: o.pop("stamp"),
        lambda o: o.update(state="busy"),
        lambda o: o.update(throws=-1),
        lambda o: o.update(faults={"count": 0}),
        lambda o: o.update(braking="no"),
    ],
)
def test_malformed_status_fails(daemon_messages, breaks):
    obj = copy.deepcopy(daemon_messages[0][-1])
    breaks(obj)
    assert not _valid("status", obj)


@pytest.mark.realtime
@pytest.mark.parametrize(
    "breaks",
    [
        lambda o: o.update(q=o["q"][:5]),
        lambda o: o.update(mode="run"),
        lambda o: o.pop("qd"),
    ],
)
def test_malformed_setpoints_fail(daemon_messages, breaks):
    obj = copy.deepcopy(daemon_messages[1][-1])
    breaks(obj)
    assert not _valid("setpoint", obj)
