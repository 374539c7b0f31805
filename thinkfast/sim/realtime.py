"""Real-time end to end: the daemon process, the simulated controller over UDP, detections over
zenoh, one throw after another, judged from the controller's joint history.

The daemon is started here (or an already running one is used: ``egm`` and ``zenoh`` endpoints
given); the controller simulator stamps every joint sample with the wall clock so the judge can
compare it with the throw's true flight. A feint is judged by
:func:`~thinkfast.sim.judge.judge_feint` instead (how far the shield left home, home again).
"""

from __future__ import annotations

import collections
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from thinkfast.contract import keys
from thinkfast.contract.camera_mode import CameraSetup
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.decide.tree_view import BALL_RADIUS
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import Robot
from thinkfast.sim.camera import CameraModelConfig, mode_model, observe
from thinkfast.sim.child_log import log_text
from thinkfast.sim.controller import SimController, servo_for
from thinkfast.sim.controller_runner import ControllerRunner
from thinkfast.sim.judge import FEINT_WINDOW, judge, judge_feint
from thinkfast.sim.publisher import publish_detections
from thinkfast.sim.throws import Throw, plane_crossing
from thinkfast.sim.watchdog import SILENCE, DaemonGone, Watchdog  # noqa: F401 (DaemonGone: API)

GAP = 3.5  # s between throws: crossing + return home + the contract's 3 s
READY_TIMEOUT = 60.0  # s for a started daemon to answer EGM and be heard on zenoh, both ways
LOOPBACK_ZENOH = Path(__file__).with_name("loopback_zenoh.json5")  # the daemon's zenoh session


class WallClockSim(SimController):
    """A simulated controller whose history also records the wall clock of every sample."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # as many samples as the history keeps (``max_history``; None: all)
        self.wall: collections.deque = collections.deque(maxlen=kwargs.get("max_history"))

    def step(self, dt: float) -> None:
        super().step(dt)
        self.wall.append((time.time(), self.q.copy()))

    def joint_history(self, since: float) -> tuple[np.ndarray, np.ndarray]:
        rows = [r for r in list(self.wall) if r[0] >= since]
        return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])


class RealtimeResult(NamedTuple):
    throw_id: str
    blocked: bool
    why: str  # a verdict of the judge, or "feint"
    miss_distance: float
    flight_time: float
    kind: str = "still"
    displacement: float = float("nan")  # feint: largest shield distance from home [m]
    home_again: bool = False  # feint: home again within FEINT_WINDOW of the ball stopping


def start_daemon(
    tree: Path,
    planner: str,
    egm_port: int,
    zenoh_port: int,
    prefix: str,
    record: Path | None,
    config: Path | None,
    extra: tuple[str, ...] = (),
    preexec_fn=None,
) -> subprocess.Popen:
    """Start ``thinkfast-run`` with loopback endpoints (``extra``: more options), its zenoh
    session without multicast scouting unless ``extra`` gives a ``--zenoh-config``.

    Its stderr goes to ``proc.log`` (a temporary file), read back when it fails. ``preexec_fn``
    runs in the child before the daemon starts (e.g. resource limits).
    """
    exe = Path(sys.executable).parent / "thinkfast-run"
    cmd = [
        str(exe),
        "--tree",
        str(tree),
        "--planner",
        planner,
        "--egm-bind",
        f"127.0.0.1:{egm_port}",
        "--zenoh-listen",
        f"tcp/127.0.0.1:{zenoh_port}",
        "--key-prefix",
        prefix,
    ]
    if record:
        cmd += ["--record", str(record)]
    if config:
        cmd += ["--config", str(config)]
    if "--zenoh-config" not in extra:  # no multicast scouting: see loopback_zenoh.json5
        cmd += ["--zenoh-config", str(LOOPBACK_ZENOH)]
    cmd += list(extra)
    log = tempfile.TemporaryFile(mode="w+")  # its log: read back only if it fails
    proc = subprocess.Popen(cmd, stderr=log, text=True, preexec_fn=preexec_fn)
    proc.log = log  # type: ignore[attr-defined]
    return proc


def daemon_log(proc: subprocess.Popen) -> str:
    """What a daemon started by :func:`start_daemon` wrote to stderr so far."""
    return log_text(proc.log)


def daemon_says(proc: subprocess.Popen, text: str, timeout: float) -> str | None:
    """The first line of the daemon's log (:func:`daemon_log`) holding ``text``, once it is
    written (polled every 0.1 s for ``timeout`` [s]); None when it was not.

    Raises:
        RuntimeError: the daemon exited first (its log in the message).
    """
    deadline = time.monotonic() + timeout
    while True:
        log = daemon_log(proc)
        line = next((ln for ln in log.splitlines() if text in ln), None)
        if line is not None or time.monotonic() > deadline:
            return line
        if proc.poll() is not None:
            raise RuntimeError(f"thinkfast-run exited: {log.strip()}")
        time.sleep(0.1)


def run_throws(
    robot: Robot,
    throws: list[Throw],
    egm: tuple[str, int],
    zenoh_endpoint: str,
    prefix: str,
    seed: int,
    extrinsic: CameraExtrinsic,
    report=print,
    camera: CameraModelConfig | None = None,
    frames=None,
    controller: tuple[WallClockSim, ControllerRunner] | None = None,
    zenoh_config: Path | None = None,
) -> list[RealtimeResult]:
    """Throw every ball at a running daemon and judge it; ``report`` gets one line per throw.

    ``camera``: the camera model (None: the mode and rate of ``extrinsic`` when it is a run
    config's :class:`~thinkfast.contract.camera_mode.CameraSetup`, else the default model).

    ``frames``: a :class:`~thinkfast.sim.frame_stream.FrameStream` to publish rendered camera
    frames (for a detector) instead of detections. ``controller``: the simulated controller
    already talking EGM to the daemon, and its runner (the simulated IRC5's; kept running);
    None: one is started at the home pose on ``egm`` and stopped at the end. ``zenoh_config``:
    the throws' zenoh configuration (a secured cell's camera node, ``camera-<id>.json5`` of
    ``thinkfast-cell certs``), connecting to ``zenoh_endpoint``; None: a plain peer.
    """
    if camera is None:
        setup = extrinsic if isinstance(extrinsic, CameraSetup) else CameraSetup()
        camera = mode_model(setup)
    if robot.placement is not None:  # the throws fly in the plane's frame: so does the camera
        extrinsic = robot.placement.camera(extrinsic)
    kin = Kinematics(robot)
    if controller is None:
        sim = WallClockSim(servo_for(robot), q0=robot.home)
        runner = ControllerRunner(sim, egm).start()
    else:
        sim, runner = controller
    session = open_peer(connect=[zenoh_endpoint], config_file=zenoh_config)
    results = []
    try:
        dog = Watchdog(runner, session, prefix, egm, SILENCE)
        detections = session.declare_publisher(keys.detections(prefix))
        try:  # a second of EGM, zenoh routes both ways: conditions, not a sleep (a slow host)
            dog.wait_ready(lambda: detections.matching_status.matching, READY_TIMEOUT, len(throws))
        finally:
            detections.undeclare()
        for i, th in enumerate(throws):
            dog.check(i, len(throws))
            if frames is not None:  # frames in real time from the ball's appearance in the hand
                t0 = time.time() + 0.3 + th.t_release
                frames.publish_throw(th, extrinsic, throw_rng(seed, i), t0)
            else:
                # a swing is seen in real time from the ball's appearance; still throws keep
                # their timing (hold frames older than 0.3 s before the release go out at once)
                t0 = time.time() + 0.3 + (th.t_release if th.kind != "still" else 0.0)
                publish_throw(session, prefix, th, throw_rng(seed, i), extrinsic, t0, camera)
            if th.kind == "feint":
                dog.sleep_until(t0 + FEINT_WINDOW + 0.3, i, len(throws))
                t_hist, q_hist = sim.joint_history(t0 - th.t_release - 0.5)
                f = judge_feint(t_hist, q_hist, kin, robot.home, t0, FEINT_WINDOW)
                results.append(
                    RealtimeResult(th.id, False, "feint", float("nan"), float(th.flight_time),
                                   "feint", f.displacement, f.home_again)
                )  # fmt: skip
                report(
                    f"throw {i + 1:3d}/{len(throws)} {th.id:>10}: FEINT -> shield moved "
                    f"{f.displacement:.3f} m, home again: {'yes' if f.home_again else 'no'}"
                )
                dog.sleep_until(t0 + FEINT_WINDOW + 1.0, i + 1, len(throws))
                continue
            cross = plane_crossing(th)
            dog.sleep_until(t0 + cross.t + 0.3, i, len(throws))
            r = judge_throw(th, *sim.joint_history(t0 - 1.0), kin, t0)._replace(kind=th.kind)
            results.append(r)
            report(throw_line(i, len(throws), th, r))
            # between throws the contract's gap; after the last, only until the arm is home
            last = i + 1 == len(throws)
            dog.sleep_until(t0 + cross.t + GAP, i + 1, len(throws), until_idle=last)
    finally:
        if controller is None:
            runner.stop()
            runner.join(2.0)
        session.close()
    return results


def throw_rng(seed: int, i: int) -> np.random.Generator:
    """The camera noise of throw ``i`` of a run seeded ``seed``."""
    return np.random.default_rng(seed * 100_003 + i)


def publish_throw(
    session,
    prefix: str,
    th: Throw,
    rng: np.random.Generator,
    extrinsic: CameraExtrinsic,
    t0: float,
    camera: CameraModelConfig = CameraModelConfig(),
    stop=None,
):
    """Publish what the camera sees of ``th`` in real time, released at wall time ``t0`` [s]
    (detections already due go out at once); blocks until the last one is out. The schedule is
    :func:`~thinkfast.sim.publisher.send_detections` (the tests' hand-made throws use it too)."""
    dets = observe(th, camera, extrinsic, rng, 0.0)
    return publish_detections(session, keys.detections(prefix), dets, t0_wall=t0, stop=stop)


def judge_throw(th: Throw, t_hist, q_hist, kin: Kinematics, t0: float) -> RealtimeResult:
    """Judge ``th`` released at wall time ``t0`` against the arm's history (wall times, joints)."""
    v = judge(th, t_hist, q_hist, kin, th.plane_x, BALL_RADIUS, t_release_wall=t0)
    return RealtimeResult(
        th.id, bool(v.blocked), v.why, float(v.miss_distance), float(th.flight_time)
    )


def throw_line(i: int, n: int, th: Throw, r: RealtimeResult) -> str:
    """One report line for throw ``i`` of ``n``."""
    cross = plane_crossing(th)
    return (
        f"throw {i + 1:3d}/{n} {th.id:>10}: flight {th.flight_time:.2f} s, "
        f"crossing ({cross.y:+.2f}, {cross.z:.2f}) m -> "
        f"{'BLOCKED' if r.blocked else r.why} (miss {r.miss_distance:.3f} m)"
    )


def run_with_daemon(
    tree: Path,
    planner: str,
    robot: Robot,
    throws,
    seed: int,
    extrinsic: CameraExtrinsic,
    prefix: str = "thinkfast",
    record: Path | None = None,
    config: Path | None = None,
    report=print,
    frames: str | None = None,
    detect_config: Path | None = None,
    daemon_args: tuple[str, ...] = (),
):
    """Start a daemon, throw, stop it (SIGINT: it brakes and exits 0); returns the results.

    ``daemon_args``: more ``thinkfast-run`` options (e.g. ``("--rerun", "spawn")``).

    ``frames`` (``"hd720"`` or ``"vga"``): publish rendered camera frames to a ``thinkfast-detect``
    process (configured by ``detect_config``) instead of detections to the daemon.
    """
    egm_port, zport = free_tcp_port(), free_tcp_port()
    proc = start_daemon(tree, planner, egm_port, zport, prefix, record, config, daemon_args)
    pipeline = None
    try:
        wait_port(proc, zport)
        if "--foxglove" in daemon_args:  # logged once its server listens (the port may be 0)
            line = daemon_says(proc, "foxglove on ws://", READY_TIMEOUT)
            report(f"live view in Foxglove: {line.rsplit(' ', 1)[-1] if line else '?'}")
        if frames is not None:
            from thinkfast.sim.frame_stream import FramePipeline

            ep = f"tcp/127.0.0.1:{zport}"
            pipeline = FramePipeline(prefix, ep, frames, seed, detect_config)
        return run_throws(
            robot,
            throws,
            ("127.0.0.1", egm_port),
            f"tcp/127.0.0.1:{zport}",
            prefix,
            seed,
            extrinsic,
            report,
            frames=pipeline.stream if pipeline is not None else None,
        )
    finally:
        if pipeline is not None:
            report(f"thinkfast-detect: {pipeline.close()}")
        stop_daemon(proc)


def stop_daemon(
    proc: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 10.0
) -> int | None:
    """Stop a daemon started by :func:`start_daemon`: ``sig`` (SIGINT or SIGTERM: it brakes
    while the controller still talks to it, then exits 0), killed after ``timeout`` [s].

    Returns:
        its exit status; None when it had to be killed.
    """
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return None


def wait_port(proc: subprocess.Popen, port: int, timeout: float = 30.0) -> None:
    """Wait until the daemon ``proc`` listens on TCP ``port`` (its zenoh endpoint)."""
    import socket

    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"thinkfast-run exited: {daemon_log(proc).strip()}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise RuntimeError("thinkfast-run did not open its zenoh port")
