"""The real ``thinkfast-detect`` process over real zenoh sessions on loopback: frames in,
contract detections out; malformed frames and boxes counted by reason; external boxes; CLI
errors."""

import json
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from conftest import assert_one_line_error, run_cli

from tests.daemon_harness import until
from thinkfast.contract import keys
from thinkfast.contract.detection import Detection, parse_detection
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.perception.frame import encode_frame, parse_frame
from thinkfast.sim.camera import CameraModelConfig
from thinkfast.sim.images import FrameRenderConfig, FrameRenderer

# a narrow 320 x 180 camera with the HD720 focal length keeps frames small (0.9 MB) in tests
CAM = CameraModelConfig(image_size=(320, 180))
F, CX, CY = CAM.focal_px, 159.5, 89.5


class Detector:
    """A ``thinkfast-detect`` process listening on loopback and a zenoh peer connected to it."""

    def __init__(self, directory: Path, *args: str, config: str = "", prefix: str = "pt"):
        self.port = free_tcp_port()
        conf = directory / "detect.toml"  # status at 50 Hz: send() waits for each frame's count
        conf.write_text("status_rate = 50.0\n" + config)
        exe = Path(sys.executable).parent / "thinkfast-detect"
        cmd = [str(exe), "--zenoh-listen", f"tcp/127.0.0.1:{self.port}", "--key-prefix", prefix]
        cmd += ["--config", str(conf)]
        self.proc = subprocess.Popen([*cmd, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)  # fmt: skip
        self.sent = 0
        self.detections: list[bytes] = []
        self.status: list[dict] = []
        self.session = self._connect()
        self.session.declare_subscriber(
            keys.detections(prefix), lambda s: self.detections.append(s.payload.to_bytes())
        )
        self.session.declare_subscriber(
            keys.detector_status(prefix),
            lambda s: self.status.append(json.loads(s.payload.to_bytes())),
        )
        block = zenoh.CongestionControl.BLOCK  # never drop: the counts must be exact
        self.frames = self.session.declare_publisher(
            keys.camera_frame(prefix), congestion_control=block
        )
        self.boxes = self.session.declare_publisher(
            keys.camera_boxes(prefix), congestion_control=block
        )
        deadline = time.time() + 30
        while not self.status and time.time() < deadline:
            assert self.proc.poll() is None, self.proc.stderr.read()
            time.sleep(0.05)
        assert self.status, "no status from thinkfast-detect"
        # the routes for the publishers: the detector's subscribers known here
        source = args[args.index("--source") + 1] if "--source" in args else "colour"
        subscribed = [self.frames] + ([self.boxes] if source != "colour" else [])
        while not all(p.matching_status.matching for p in subscribed):
            assert time.time() < deadline, "thinkfast-detect's subscribers were never matched"
            time.sleep(0.01)

    def _connect(self):
        """A session once the detector listens: a session opened before that would retry
        after zenoh's own back-off (1, 2, 4 s), not when the port opens."""
        deadline = time.time() + 30
        while True:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    break
            assert self.proc.poll() is None, self.proc.stderr.read()
            assert time.time() < deadline, "thinkfast-detect did not listen"
            time.sleep(0.05)
        while True:
            try:
                return open_peer(connect=[f"tcp/127.0.0.1:{self.port}"])
            except Exception:
                assert self.proc.poll() is None, self.proc.stderr.read()
                if time.time() > deadline:
                    raise
                time.sleep(0.1)

    def send(self, payload, pause: float = 0.0) -> None:
        """Publish a frame and wait until the detector has counted it (its ring of 4 frames
        never overflows, however loaded the machine), then ``pause`` more."""
        self.frames.put(payload)
        self.sent += 1
        deadline = time.time() + 20
        while self.status[-1]["frames"]["received"] < self.sent:
            assert time.time() < deadline, "the detector did not count a frame"
            time.sleep(0.005)
        time.sleep(pause)

    def stop(self) -> tuple[int, dict]:
        time.sleep(0.3)
        self.proc.send_signal(signal.SIGINT)
        out, err = self.proc.communicate(timeout=15)
        self.session.close()
        assert out.strip(), err
        return self.proc.returncode, json.loads(out.strip().splitlines()[-1])


def _with_header(payload: bytes, **changes) -> bytes:
    """``payload`` with header fields replaced (the header length updated)."""
    n = struct.unpack_from("<I", payload, 4)[0]
    header = {**json.loads(payload[8 : 8 + n]), **changes}
    text = json.dumps(header).encode()
    return payload[:4] + struct.pack("<I", len(text)) + text + payload[8 + n :]


def _renderer(**kw):
    return FrameRenderer(FrameRenderConfig(**kw), CAM, seed=4)


@pytest.mark.realtime
def test_frames_become_contract_detections_in_base_with_the_frame_stamps(tmp_path):
    ext = CameraExtrinsic(xyz=(0.46, 0.1, 0.3), rpy=(0.0, 0.05, -0.1))
    cfg = 'frame = "base"\n[camera]\nxyz = [0.46, 0.1, 0.3]\nrpy = [0.0, 0.05, -0.1]\n'
    det = Detector(tmp_path, config=cfg)
    r = _renderer()
    rng = np.random.default_rng(0)
    truth = {}
    for k in range(30):  # a ball coming from 4 m to 2 m, drifting across the image
        p = np.array([4.0 - k / 15, 0.1 - k / 150, 0.05])
        stamp = time.time()
        payload, t = r.render(stamp, 100 + k, p, np.array([-12.0, 1.0, 0.0]), 0.15, rng)
        truth[100 + k] = (stamp, ext.rotation() @ t.position + ext.xyz)
        det.send(payload)
    code, counts = det.stop()
    assert code == 0
    assert counts["frames"]["received"] == counts["frames"]["detected"] == 30
    assert counts["published"] == len(det.detections) == 30
    for payload in det.detections:
        assert set(json.loads(payload)) == {"stamp", "position", "frame", "confidence", "seq"}
        d = parse_detection(payload)
        assert isinstance(d, Detection) and d.frame == "base"
        stamp, p_base = truth[d.seq]
        assert d.stamp == stamp
        assert np.linalg.norm(d.position - p_base) < 0.05, (d.position, p_base)
        assert 0.0 < d.confidence <= 1.0


@pytest.mark.realtime
def test_malformed_frames_are_counted_by_reason_and_dropped_without_a_crash(tmp_path):
    det = Detector(tmp_path)
    r = _renderer()
    rng = np.random.default_rng(1)
    ball = np.array([2.5, 0.0, 0.0])
    good, _ = r.render(time.time(), 1, ball, None, 0.1, rng)
    good = bytes(good)
    f = parse_frame(good)
    nan_cloud = encode_frame(time.time(), (F, F, CX, CY), f.image, np.full_like(f.xyz, np.nan), 2)
    no_ball, _ = r.render(time.time(), 3, None, None, 0.1, rng)
    head = good.index(b"}") + 1
    sent = {
        "bad_magic": [np.random.default_rng(k).bytes(5000) for k in range(5)],
        "too_short": [b"", b"TFC"],
        "bad_header": [b"TFCF" + (50).to_bytes(4, "little") + b"{not json" + bytes(41)],
        "bad_length": [good[: head + 1000], good[:-1], good + b"x"],
        "bad_image": [good.replace(b'"bgr8"', b'"rgb8"', 1)],
        "bad_stamp": [_with_header(good, stamp=-5.0), _with_header(good, stamp="now")],
        "bad_xyz": [_with_header(good, xyz={"dtype": "float64", "bytes": 1})],
    }
    det.send(good)
    for payloads in sent.values():
        for p in payloads:
            det.send(p)
    det.send(nan_cloud)
    det.send(bytes(no_ball))
    det.send(good)
    code, counts = det.stop()
    assert code == 0
    fr = counts["frames"]
    assert fr["received"] == 3 + sum(len(v) for v in sent.values()) + 1
    assert {k: v for k, v in fr["rejected"].items() if v} == {k: len(v) for k, v in sent.items()}
    assert fr["missed"]["no_depth"] == 1 and fr["missed"]["no_ball"] == 1
    assert fr["detected"] == 2 == len(det.detections)
    assert det.status[-1]["frames"]["rejected"]["bad_magic"] == 5  # status says it too


@pytest.mark.realtime
def test_external_boxes_locate_a_ball_the_colour_filter_cannot_see(tmp_path):
    det = Detector(tmp_path, "--source", "boxes")
    r = _renderer(ball_bgr=(128, 128, 128))  # a grey ball: no colour to find
    rng = np.random.default_rng(2)
    p = np.array([3.0, 0.05, -0.02])
    u, v = CX - F * p[1] / p[0], CY - F * p[2] / p[0]
    rad = F * 0.0335 / p[0]
    box = {"xyxy": [u - rad + 0.5, v - rad + 0.5, u + rad + 0.5, v + rad + 0.5], "score": 0.9}

    def frame(seq):
        payload, _ = r.render(1000.0 + seq, seq, p, None, 0.1, rng)
        return bytes(payload)

    def boxes(seq, items):
        det.boxes.put(json.dumps({"stamp": 1000.0 + seq, "seq": seq, "boxes": items}).encode())

    det.send(frame(1))
    boxes(1, [box])  # boxes after their frame (a detector runs on the frame first)
    time.sleep(0.03)
    boxes(2, [box])  # and before it
    time.sleep(0.03)
    det.send(frame(2))
    det.send(frame(3), pause=0.15)  # no boxes ever: dropped after boxes.wait
    det.send(frame(4))
    boxes(4, [])  # the external detector saw no ball
    det.boxes.put(b"{oops")
    code, counts = det.stop()
    assert code == 0
    assert counts["frames"]["detected"] == 2 and len(det.detections) == 2
    assert counts["frames"]["missed"]["no_box"] == 1 and counts["frames"]["missed"]["no_ball"] == 1
    assert counts["boxes"]["received"] == 4 and counts["boxes"]["matched"] == 3
    assert counts["boxes"]["rejected"]["not_json"] == 1
    for payload in det.detections:
        d = parse_detection(payload)
        assert np.linalg.norm(d.position - p) < 0.03 and d.seq in (1, 2)


def test_a_slow_consumer_keeps_the_newest_frames_and_counts_the_skipped_ones(tmp_path):
    det = Detector(tmp_path)
    r = _renderer()
    rng = np.random.default_rng(3)
    payloads = [bytes(r.render(time.time(), k, np.array([2.0, 0, 0]), None, 0.1, rng)[0])
                for k in range(1, 41)]  # fmt: skip
    det.send(payloads[0])  # counted: seq gaps before a detector's first frame cannot be known
    for pl in payloads[1:]:  # as fast as zenoh takes them
        det.frames.put(pl)
    # however many it skipped, the last frame is detected: stop only then (a fixed wait once
    # stopped it with frame 40 still on its way)
    last = lambda: det.detections and json.loads(det.detections[-1])["seq"] == 40  # noqa: E731
    assert until(last, 60.0), "the last frame was never detected"
    code, counts = det.stop()
    fr = counts["frames"]
    assert code == 0 and fr["received"] + fr["skipped"] == 40
    assert fr["detected"] == fr["received"]
    assert json.loads(det.detections[-1])["seq"] == 40  # the last frame is never lost


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (("--frame", "sideways"), ("--frame", "sideways")),
        (("--source", "radar"), ("--source", "radar")),
        (("--config", "/nonexistent/d.toml"), ("/nonexistent/d.toml", "not found")),
    ],
)
def test_bad_options_are_one_line_errors(args, needles):
    assert_one_line_error(run_cli("thinkfast-detect", *args, timeout=60), *needles)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[colour]\nbogus = 1\n", "colour.bogus"),
        ("[colour]\nhsv_low = [50, 90, 60]\n", "colour.hsv_low"),
        ("[shrink]\nfar = 2.0\n", "shrink.far"),
        ("source = 'lidar'\n", "source"),
    ],
)
def test_bad_config_values_name_their_key(tmp_path, text, key):
    cfg = tmp_path / "d.toml"
    cfg.write_text(text)
    assert_one_line_error(run_cli("thinkfast-detect", "--config", str(cfg), timeout=60), key)


def test_sigterm_also_ends_it_with_exit_0(tmp_path):
    det = Detector(tmp_path)
    det.proc.send_signal(signal.SIGTERM)
    out, _ = det.proc.communicate(timeout=15)
    det.session.close()
    assert det.proc.returncode == 0 and json.loads(out)["frames"]["received"] == 0


@pytest.mark.realtime
def test_auto_source_falls_back_to_the_colour_filter_when_no_boxes_come(tmp_path):
    det = Detector(tmp_path, "--source", "auto")
    r = _renderer()
    payload, truth = r.render(
        50.0, 1, np.array([2.5, 0.0, 0.0]), None, 0.1, np.random.default_rng(4)
    )
    det.send(bytes(payload), pause=0.2)  # longer than boxes.wait
    code, counts = det.stop()
    assert code == 0 and counts["frames"]["detected"] == 1 and counts["boxes"]["received"] == 0
    d = parse_detection(det.detections[0])
    assert d.stamp == 50.0 and np.linalg.norm(d.position - truth.position) < 0.03
