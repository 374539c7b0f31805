"""Rendered camera frames of simulated throws over zenoh in real time, and the detector process.

``thinkfast-sim run --frames`` uses this instead of publishing detections: every frame of a
throw (the camera model's frame grid, from the ball's appearance in the hand to just past the
plane) is rendered by :class:`~thinkfast.sim.images.FrameRenderer` and published on
``<prefix>/camera/frame`` at capture time plus the bridge's latency; a ``thinkfast-detect``
process turns them into detections for the daemon.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import zenoh

from thinkfast.contract import keys
from thinkfast.contract.camera_mode import ZED_MODES
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.sim.camera import CameraModelConfig
from thinkfast.sim.child_log import log_text
from thinkfast.sim.images import FrameRenderConfig, FrameRenderer
from thinkfast.sim.throws import Throw, ball_states, observed_until

RESOLUTIONS = {k.lower(): (m.image_size, m.focal_px) for k, m in ZED_MODES.items()}
VGA_DETECT = "[colour]\nsearch_step = 1\nopen_px = 1\nmin_area = 2\n"  # balls 2-3 px wide at 6-9 m


class FrameReport(NamedTuple):
    """Frames sent for one throw, with the ball in view, and the worst lateness [s]."""

    sent: int
    with_ball: int
    max_late: float


class FrameStream:
    """Renders and publishes the frames of throws on one zenoh session.

    Args:
        session: an open zenoh session.
        prefix: key prefix.
        camera: camera model (rate, exposure, noise); ``resolution`` overrides size and focus.
        resolution: ``"hd720"`` or ``"vga"``.
        render: scene and XYZ encoding (default: float16 XYZ, at half resolution at HD720).
        seed: scene seed.
    """

    def __init__(
        self,
        session: zenoh.Session,
        prefix: str,
        camera: CameraModelConfig = CameraModelConfig(),
        resolution: str = "hd720",
        render: FrameRenderConfig | None = None,
        seed: int = 0,
    ):
        size, focal = RESOLUTIONS[resolution]
        self.camera = dataclasses.replace(camera, image_size=size, focal_px=focal)
        if render is None:  # 4.1 MB a frame at HD720; VGA keeps every cloud pixel (2.3 MB)
            render = FrameRenderConfig(
                xyz_dtype="float16", xyz_step=2 if resolution == "hd720" else 1
            )
        self.renderer = FrameRenderer(render, self.camera, seed)
        self.pub = session.declare_publisher(keys.camera_frame(prefix))
        self.seq = 0

    def publish_throw(
        self,
        throw: Throw,
        extrinsic: CameraExtrinsic,
        rng: np.random.Generator,
        t0_wall: float,
        stop: threading.Event | None = None,
    ) -> FrameReport:
        """Publish every frame of ``throw`` released at wall time ``t0_wall`` [s]."""
        cam = self.camera
        period = 1.0 / cam.rate
        until = observed_until(throw, cam.after_crossing)
        n = int(math.floor((until + throw.t_release) * cam.rate)) + 1
        t = -throw.t_release + rng.uniform(0.0, period) + period * np.arange(n)
        t = t[t <= until]
        p_base, v_base = ball_states(throw, t)
        R, c = extrinsic.rotation(), extrinsic.translation()
        p_cam, v_cam = (p_base - c) @ R, v_base @ R
        sigma_disp = rng.uniform(*cam.disparity_sigma)
        latency = cam.latency[0]
        sent = seen = 0
        late = 0.0
        for i in range(len(t)):
            if stop is not None and stop.is_set():
                break
            due = t0_wall + t[i] + latency
            wait = due - time.time()
            if wait > 0.0:
                time.sleep(wait)
            self.seq += 1
            payload, truth = self.renderer.render(
                t0_wall + t[i], self.seq, p_cam[i], v_cam[i], sigma_disp, rng
            )
            self.pub.put(payload)
            sent += 1
            seen += truth.position is not None
            late = max(late, time.time() - due)
        return FrameReport(sent, seen, late)


def start_detector(
    prefix: str, listen_port: int, connect: str, config: Path | None = None
) -> subprocess.Popen:
    """Start ``thinkfast-detect`` listening on a loopback port and connected to ``connect``.

    Its stderr goes to ``proc.log`` (a temporary file); its stdout (the final counts) is a pipe.
    """
    exe = Path(sys.executable).parent / "thinkfast-detect"
    cmd = [
        str(exe),
        "--key-prefix",
        prefix,
        "--zenoh-listen",
        f"tcp/127.0.0.1:{listen_port}",
        "--zenoh-connect",
        connect,
    ]
    if config:
        cmd += ["--config", str(config)]
    log = tempfile.TemporaryFile(mode="w+")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True)
    proc.log = log  # type: ignore[attr-defined]
    return proc


def wait_detector(session: zenoh.Session, prefix: str, proc: subprocess.Popen, timeout=30.0):
    """Wait for the detector's status on ``session``; raises RuntimeError if it never comes."""
    heard = threading.Event()
    sub = session.declare_subscriber(keys.detector_status(prefix), lambda s: heard.set())
    try:
        deadline = time.time() + timeout
        while not heard.wait(0.1):
            if proc.poll() is not None:
                raise RuntimeError(f"thinkfast-detect exited: {log_text(proc.log).strip()}")
            if time.time() > deadline:
                raise RuntimeError("no status from thinkfast-detect")
    finally:
        sub.undeclare()


def stop_detector(proc: subprocess.Popen, timeout: float = 10.0) -> str:
    """SIGINT the detector; its final counts (one JSON line), or '' if it did not say."""
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return (out or "").strip()


class FramePipeline:
    """A ``thinkfast-detect`` process fed by a :class:`FrameStream` (``thinkfast-sim run
    --frames``): the detector listens on a free loopback port and connects to ``daemon``.

    Args:
        prefix: key prefix.
        daemon: zenoh endpoint of the daemon (where detections go).
        resolution: ``"hd720"`` or ``"vga"``.
        seed: scene seed.
        config: detector configuration (TOML), or None (defaults; at VGA, :data:`VGA_DETECT`).
    """

    def __init__(
        self,
        prefix: str,
        daemon: str,
        resolution: str = "hd720",
        seed: int = 0,
        config: Path | None = None,
    ):
        from thinkfast.contract.zenoh_session import free_tcp_port, open_peer

        port = free_tcp_port()
        self._tmp = None
        if config is None and resolution == "vga":
            self._tmp = tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False)
            self._tmp.write(VGA_DETECT)
            self._tmp.close()
            config = Path(self._tmp.name)
        self.proc = start_detector(prefix, port, daemon, config)
        self.session = None
        try:
            deadline = time.time() + 30.0
            while self.session is None:
                try:
                    self.session = open_peer(connect=[f"tcp/127.0.0.1:{port}"])
                except Exception:  # not listening yet
                    if self.proc.poll() is not None or time.time() > deadline:
                        raise
                    time.sleep(0.2)
            wait_detector(self.session, prefix, self.proc)
            self.stream = FrameStream(self.session, prefix, resolution=resolution, seed=seed)
        except BaseException:
            self.close()
            raise

    def close(self) -> str:
        """Stop the detector and the session; the detector's final counts (JSON line)."""
        counts = stop_detector(self.proc) if self.proc.poll() is None else ""
        if self._tmp is not None:
            Path(self._tmp.name).unlink(missing_ok=True)
            self._tmp = None
        if self.session is not None:
            self.session.close()
            self.session = None
        return counts
