"""Detections over zenoh in real time: two loopback sessions; the schedule on a fake clock."""

import json
import threading
import time

import numpy as np
import pytest

from thinkfast.contract import keys
from thinkfast.contract.detection import Detection, parse_detection
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.publisher import publish_detections
from thinkfast.sim.throws import ThrowConfig, sample_throws

KEY = keys.detections("simtest")


@pytest.fixture(scope="module")
def detections():
    (th,) = sample_throws(ThrowConfig(), 1, seed=21)
    return observe(th, CameraModelConfig(), CameraExtrinsic(), np.random.default_rng(0))


def _wait_for_route(pub, sub, timeout=5.0):
    """Probe a side key until the subscriber session hears it (the peers are connected)."""
    heard = []
    probe = sub.declare_subscriber("simtest/probe", lambda s: heard.append(1))
    deadline = time.monotonic() + timeout
    while not heard and time.monotonic() < deadline:
        pub.put("simtest/probe", b"?")
        time.sleep(0.02)
    probe.undeclare()
    assert heard, "the two loopback sessions never connected"


@pytest.mark.realtime
def test_everything_published_arrives_in_order_and_on_time(sessions, detections):
    pub, sub = sessions
    got = []  # (arrival wall time, payload): the callback only appends
    listener = sub.declare_subscriber(
        KEY, lambda s: got.append((time.time(), s.payload.to_bytes()))
    )
    _wait_for_route(pub, sub)
    t0 = time.time() + 0.2 - detections[0].capture_stamp  # shift the throw to start in 0.2 s
    report = publish_detections(pub, KEY, detections, t0_wall=t0)
    time.sleep(0.1)
    listener.undeclare()
    assert report.sent == len(detections) == len(got)
    parsed = [parse_detection(p) for _, p in got]
    assert all(isinstance(d, Detection) for d in parsed)
    assert [d.seq for d in parsed] == [sd.seq for sd in detections]
    for d, sd in zip(parsed, detections, strict=True):
        assert d.stamp == pytest.approx(sd.capture_stamp + t0, abs=1e-6)
    late = np.array(
        [arr - (t0 + sd.delivery_time) for (arr, _), sd in zip(got, detections, strict=True)]
    )
    assert late.min() > -1e-3  # never early (lateness figures: bench/wallclock.py)


class _FakeBus:
    """A session whose puts are recorded (clock, payload, source) on a clock that sleep moves.

    Each publisher is declared on a real loopback session too, for its real entity id: the
    publisher attaches that id as every sample's source (what a secured daemon checks).
    """

    def __init__(self, session, work=0.003):
        self.session, self.now, self.work, self.sent, self.sleeps = session, 100.0, work, [], []

    def clock(self):
        return self.now

    def sleep(self, s):
        self.sleeps.append(s)
        self.now += s

    def declare_publisher(self, key):
        bus, real = self, self.session.declare_publisher(key)

        class _Pub:
            id = real.id

            def put(self, payload, source_info=None):
                bus.sent.append((bus.now, payload, source_info))
                bus.now += bus.work  # each put costs time: an absolute schedule absorbs it

            def undeclare(self):
                real.undeclare()

        return _Pub()


def test_schedule_is_absolute_so_slow_puts_do_not_accumulate_drift(sessions, detections):
    bus = _FakeBus(sessions[0], work=0.003)
    publish_detections(bus, KEY, detections, t0_wall=100.5, clock=bus.clock, sleep=bus.sleep)
    due = 100.5 + np.array([sd.delivery_time for sd in detections])
    sent = np.array([t for t, _, _ in bus.sent])
    expect = [due[0]]  # each sample at its due time, or right after the previous put if later
    for d in due[1:]:
        expect.append(max(d, expect[-1] + bus.work))
    np.testing.assert_allclose(sent, expect, rtol=0, atol=1e-9)
    stamps = [json.loads(p)["stamp"] for _, p, _ in bus.sent]
    np.testing.assert_allclose(stamps, 100.5 + np.array([d.capture_stamp for d in detections]))
    # every sample names its publisher (this session's id) and is numbered in order
    sources = [info for _, _, info in bus.sent]
    assert {str(info.source_id.zid) for info in sources} == {str(sessions[0].info.zid())}
    assert [info.source_sn for info in sources] == list(range(len(detections)))


def test_samples_already_due_go_out_at_once_and_stop_is_honoured(sessions, detections):
    bus = _FakeBus(sessions[0], work=0.0)
    bus.now = 1e6  # far behind schedule
    report = publish_detections(bus, KEY, detections, clock=bus.clock, sleep=bus.sleep)
    assert report.sent == len(detections) and not bus.sleeps
    stop = threading.Event()
    stop.set()
    assert publish_detections(bus, KEY, detections, stop=stop, clock=bus.clock).sent == 0
