"""Runs the real ``thinkfast-run`` process against a simulated EGM controller and zenoh peers.

Everything is real: the daemon process, its UDP socket with protobuf EGM messages from
:class:`ControllerRunner`, and zenoh sessions on loopback.
"""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import h5py
import numpy as np
import zenoh

from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import open_peer
from thinkfast.sim.camera import SimDetection
from thinkfast.sim.controller import ServoConfig, SimController
from thinkfast.sim.controller_runner import ControllerRunner
from thinkfast.sim.publisher import send_detections
from thinkfast.sim.realtime import daemon_log, start_daemon, stop_daemon, wait_port


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def until(check, timeout: float, poll: float = 0.3) -> bool:
    """Call ``check()`` every ``poll`` seconds until it is true (True) or ``timeout`` [s] has
    passed (False)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if check():
            return True
        time.sleep(poll)
    return False


class DaemonRun:
    """A daemon process with a simulated controller and a zenoh peer connected to it.

    Every run not stopped by its test is stopped after the test (conftest.py): a daemon left
    running would answer later tests' zenoh traffic and keep pytest from exiting."""

    live: set = set()  # runs not yet stopped

    def __init__(
        self,
        tree: Path,
        record: Path,
        planner: str = "tree",
        q0=None,
        extra: tuple[str, ...] = (),
        prefix: str = "thinkfast",
    ):
        self.egm_port = free_port()
        self.zport = free_port(socket.SOCK_STREAM)
        self.record = record
        self.prefix = prefix
        self.proc = start_daemon(
            tree, planner, self.egm_port, self.zport, prefix, record, None, tuple(extra)
        )
        DaemonRun.live.add(self)
        self.runner = None
        self.session = None
        self.stopped = False
        self.status: list[dict] = []
        self.setpoints: list[dict] = []
        self._wait_ready()
        self.sim = SimController(ServoConfig(), q0=q0)
        self.runner = ControllerRunner(self.sim, ("127.0.0.1", self.egm_port)).start()

    def _wait_ready(self, timeout: float = 90.0) -> None:
        deadline = time.time() + timeout
        # open the session once the daemon listens: zenoh retries a refused connect after 1, 2
        # then 4 s, which made every start take about 7 s
        wait_port(self.proc, self.zport, timeout)
        self.session = open_peer(connect=[f"tcp/127.0.0.1:{self.zport}"])
        self.session.declare_subscriber(
            keys.status(self.prefix), lambda s: self.status.append(json.loads(s.payload.to_bytes()))
        )
        self.session.declare_subscriber(
            keys.setpoints(self.prefix),
            lambda s: self.setpoints.append(json.loads(s.payload.to_bytes())),
        )
        self.pub = self.session.declare_publisher(  # block, never drop: counts must be exact
            keys.detections(self.prefix), congestion_control=zenoh.CongestionControl.BLOCK
        )
        while time.time() < deadline and not self.status:
            time.sleep(0.01)
        if not self.status:
            raise RuntimeError("no status from the daemon")
        # the first detection must reach the daemon: wait until its subscriber is known here
        # (a condition, where a fixed 0.3 s sleep used to be)
        while time.time() < deadline and not self.pub.matching_status.matching:
            time.sleep(0.01)
        if not self.pub.matching_status.matching:
            raise RuntimeError("the daemon's detection subscriber was never matched")

    def publish(self, payload: bytes) -> None:
        """Put one detection; after :meth:`stop` closed the session (a test's publisher thread
        that outlived the run) nothing is sent."""
        if self.stopped:
            return
        try:
            self.pub.put(payload)
        except Exception:  # zenoh.ZError: session closed by stop() between the test and the put
            if not self.stopped:
                raise

    def wait_state(self, state: str, timeout: float) -> bool:
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.status and self.status[-1]["state"] == state:
                return True
            time.sleep(0.02)
        return False

    def stop(self, timeout: float = 15.0) -> tuple[int, str]:
        """SIGINT the daemon (the controller keeps talking while it brakes), then stop all."""
        DaemonRun.live.discard(self)
        code = stop_daemon(self.proc, timeout=timeout)
        if self.runner is not None:
            self.runner.stop()
            self.runner.join(2.0)
        err = daemon_log(self.proc)
        self.stopped = True
        if self.session is not None:
            self.session.close()
        return -9 if code is None else code, err

    def egm_rows(self) -> np.ndarray:
        """Recorded EGM exchanges: t, seqno, q_fb (6), q_cmd (6), qd_cmd (6), braking."""
        with h5py.File(self.record) as f:
            return f["egm"][:]


def ballistic_throw(
    aim_yz,
    flight: float,
    t_release: float,
    release=(7.8, -0.2, 1.5),
    plane_x: float = 0.8,
    g: float = 9.81,
):
    """Release position (3,), velocity (3,) of a gravity-only throw reaching ``aim_yz`` on the
    plane after ``flight`` seconds, and a function giving the ball position at wall time t."""
    p0 = np.array(release, dtype=float)
    v0 = np.array(
        [
            (plane_x - p0[0]) / flight,
            (aim_yz[0] - p0[1]) / flight,
            (aim_yz[1] - p0[2] + 0.5 * g * flight**2) / flight,
        ]
    )

    def at(t: float) -> np.ndarray:
        s = max(t - t_release, 0.0)
        return p0 + v0 * s + np.array([0.0, 0.0, -0.5 * g * s * s])

    return p0, v0, at


def publish_throw(
    run: DaemonRun,
    at,
    t_release: float,
    flight: float,
    hold: float = 0.4,
    noise: float = 0.01,
    camera=(0.46, 0.0, 0.30),
    latency: float = 0.04,
    seed: int = 0,
) -> None:
    """Publish 50 Hz detections (camera frame) of the ball: held still, then in flight, each
    ``latency`` [s] after its capture, through ``run.publish`` (or any sender's ``publish``) on
    the package's real-time schedule (:func:`thinkfast.sim.publisher.send_detections`)."""
    rng = np.random.default_rng(seed)
    cam = np.asarray(camera)
    dets, t = [], t_release - hold
    while t <= t_release + flight + 0.06:
        z = at(t) - cam + rng.normal(0.0, noise, 3)
        cov = np.eye(3) * noise**2
        dets.append(SimDetection(t, t + latency, z, len(dets) + 1, at(t), False, cov, None))
        t += 0.02
    send_detections(run.publish, dets)


def shield_distance_at_crossing(rows: np.ndarray, kin, t_cross: float, aim_yz, lag: float = 0.0):
    """Distance [m] on the plane between the shield centre (from the recorded feedback, by
    forward kinematics) and the crossing point, when the ball crosses; and the normal's x."""
    t, q_fb = rows[:, 0], rows[:, 2:8]
    i = min(int(np.searchsorted(t, t_cross + lag)), len(t) - 1)
    pose = kin.shield(q_fb[i])
    return float(np.linalg.norm(pose.centre[1:] - np.asarray(aim_yz))), pose
