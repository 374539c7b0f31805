"""Live view with Rerun: what the daemon sees, believes, decides and commands (docs/LIVE_VIEW.md).

Three layers:

* :func:`parse_sink` / :func:`open_stream`: the ``--rerun`` option (``spawn``, ``connect[=URL]``,
  ``save=FILE.rrd``) and the Rerun recording stream it opens. ``rerun-sdk`` is optional (the
  ``view`` extra); it is imported only here, and only when the option is given.
* :class:`Painter`: turns thinkfast's arrays (detections, filter belief, plane crossing, decision,
  joints) into Rerun entities (:data:`ENTITIES`) on the ``time`` timeline (Unix time [s]). Used
  by the daemon live and by ``thinkfast-sim replay --rerun`` offline (from a flight record).
* :class:`DaemonView`: the daemon's side. :meth:`DaemonView.on_detection` only queues references
  to immutable objects (the payload, the accepted detection, the belief, the segment); the work
  is done by :meth:`DaemonView.service`, which the daemon calls in its idle time (after the
  detections were taken, where the status is published), one bounded job per call. Joints are
  sampled there too, at most ``joint_rate`` times a second, from the control core's last reply
  and measured feedback. Nothing here runs inside the EGM reply; with the view off the daemon
  holds ``None`` and pays one ``is not None`` test per loop.
"""

from __future__ import annotations

import collections
import math
import time
from typing import NamedTuple

import numpy as np

from thinkfast.errors import ConfigError

APP_ID = "thinkfast"
TIMELINE = "time"  # Unix time [s]
DEFAULT_CONNECT = "rerun+http://127.0.0.1:9876/proxy"
ELLIPSOID_SIGMAS = 2.0  # half-axes of the belief and crossing ellipsoids, in standard deviations
TRAIL = 240  # detections kept in the raw and accepted trails (about 4 s at 60 Hz)
PATH_SAMPLES = 24  # shield positions drawn along the chosen motion
INITIAL_COST = 0.0015  # s: expected duration of a job before one of its kind was measured
WAIT_DECAY = 0.9995  # factor on a job kind's cost each time it waits for time
SINKS = ("spawn", "connect", "save")

# Entity paths and what each shows (docs/LIVE_VIEW.md has the same table; a test checks both).
ENTITIES = {
    "world/plane/goals": "goal grid on the blocking plane x = plane_x (static)",
    "world/detections/raw": "every detection payload received (parsed, in base), recent trail",
    "world/detections/accepted": "detections the intake accepted (in base), recent trail",
    "world/ball/mean": "filter belief: mean position, velocity arrow",
    "world/ball/covariance": f"filter belief: {ELLIPSOID_SIGMAS:g}-sigma position ellipsoid",
    "world/plane/crossing": f"predicted crossing Gaussian on the plane, {ELLIPSOID_SIGMAS:g} sigma",
    "world/plane/chosen_goal": "goal of the chosen motion",
    "world/plan/shield_path": "shield centre along the chosen motion (direct move or tree edge)",
    "world/arm/commanded": "arm at the commanded joints: joint frames joined by segments",
    "world/arm/commanded/shield": "shield disk at the commanded joints",
    "world/arm/measured": "arm at the measured joints: joint frames joined by segments",
    "world/arm/measured/shield": "shield disk at the measured joints",
    "plan/value": "value (block probability) of the chosen motion",
    "plan/motion": "the chosen motion and its value, as text",
    "joints/q_cmd": "commanded joint positions [rad], one series per joint",
    "joints/q_meas": "measured joint positions [rad], one series per joint",
    "joints/qd_cmd": "commanded joint velocities [rad/s], one series per joint",
    "events": "the daemon's events (record replay only)",
}
GREY, GREEN, ORANGE, BLUE, RED = (
    (150, 150, 150),
    (40, 200, 80),
    (255, 150, 30),
    (60, 140, 255),
    (230, 50, 50),
)


class ViewSink(NamedTuple):
    """Where the view goes: ``spawn`` a viewer, ``connect`` to one at ``target``, or ``save`` to
    the ``.rrd`` file ``target``."""

    kind: str
    target: str | None = None


def parse_sink(text: str, option: str = "--rerun") -> ViewSink:
    """``spawn``, ``connect``, ``connect=URL`` (or ``connect URL``), ``save=FILE.rrd``.

    Raises:
        ConfigError: naming ``option`` and what it accepts.
    """
    raw = text.strip()
    kind, _, target = raw.replace("=", " ", 1).partition(" ")
    target = target.strip() or None
    if kind not in SINKS:
        raise ConfigError(option, None, f"{text!r} is not spawn, connect[=URL] or save=FILE.rrd")
    if kind == "spawn" and target is not None:
        raise ConfigError(option, None, f"{text!r}: spawn takes no argument")
    if kind == "save" and target is None:
        raise ConfigError(option, None, f"{text!r}: save needs a file, save=FILE.rrd")
    if kind == "connect" and target is None:
        target = DEFAULT_CONNECT
    return ViewSink(kind, target)


def open_stream(sink: ViewSink, name: str, recording_id: str | None = None):
    """A Rerun recording stream sending to ``sink`` (imports ``rerun`` here).

    Raises:
        ConfigError: ``rerun-sdk`` is not installed, or the ``save`` file cannot be created.
    """
    try:
        import rerun as rr
    except ImportError:
        raise ConfigError(
            "--rerun", None, "needs rerun-sdk: pip install 'thinkfast[view]'"
        ) from None
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.send_recording_name(name)
    if sink.kind == "spawn":
        rec.spawn()
    elif sink.kind == "connect":
        rec.connect_grpc(sink.target)
    else:
        try:
            rec.save(sink.target)
        except Exception as exc:  # rerun raises its own errors for an unwritable path
            raise ConfigError("--rerun", None, f"cannot write {sink.target}: {exc}") from None
    return rec


# ------------------------------------------------------------------ geometry (pure)
def ellipsoid(cov: np.ndarray, sigmas: float = ELLIPSOID_SIGMAS) -> tuple[np.ndarray, np.ndarray]:
    """Half-axes (3,) [m] and orientation quaternion (x, y, z, w) of the ``sigmas`` ellipsoid
    of a 3x3 covariance [m^2] (non-finite or negative variances count as 0)."""
    c = np.nan_to_num(0.5 * (cov + cov.T))
    w, v = np.linalg.eigh(c)
    if np.linalg.det(v) < 0:
        v[:, 2] = -v[:, 2]  # a rotation, not a reflection
    return sigmas * np.sqrt(np.clip(w, 0.0, None)), matrix_quat(v)


def matrix_quat(r: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation matrix (3, 3)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_quat()


def plane_cov(o_cov: np.ndarray, thickness: float = 1e-6) -> np.ndarray:
    """3x3 covariance [m^2] in base of the crossing point on the plane x = const, from the
    crossing covariance (Y, Z, tau) (3, 3): flat along x."""
    c = np.zeros((3, 3))
    c[1:, 1:] = o_cov[:2, :2]
    c[0, 0] = thickness
    return c


def motion_text(kind: str, ref: int, goal: int, value: float | None) -> str:
    """One line on the chosen motion: a direct move, a tree edge (branch), a terminal edge, ..."""
    what = {
        "steer": f"direct move to goal {goal}",
        "edge": f"tree branch into node {ref}",
        "terminal": f"terminal edge {ref} to goal {goal}",
        "return": "return home",
        "hold": "hold",
    }.get(kind, kind)
    return what if value is None else f"{what}, value {value:.3f}"


# ------------------------------------------------------------------ painter
class Painter:
    """Logs thinkfast's quantities as the entities of :data:`ENTITIES` to one stream.

    Args:
        rec: a Rerun recording stream (:func:`open_stream`).
        robot: the robot (joint frames, shield size).
        plane_x: the blocking plane's distance [m] (x in base).
        goal_yz: goal grid (G, 2) [m] on the plane, or None when unknown.
    """

    def __init__(self, rec, robot, plane_x: float, goal_yz: np.ndarray | None):
        import rerun as rr

        from thinkfast.robot.kinematics import Kinematics

        self.rr, self.rec, self.robot = rr, rec, robot
        self.kin = Kinematics(robot)
        self.plane_x = float(plane_x)
        self.goal_yz = None if goal_yz is None else np.asarray(goal_yz, dtype=float)
        self.frames = ["base_link"] + [j.child for j in robot.chain]
        self.raw_trail: collections.deque = collections.deque(maxlen=TRAIL)
        self.acc_trail: collections.deque = collections.deque(maxlen=TRAIL)
        self._static()

    def _at(self, t: float) -> None:
        self.rec.set_time(TIMELINE, timestamp=float(t))

    def _static(self) -> None:
        rr, rec = self.rr, self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if self.goal_yz is not None and len(self.goal_yz):
            g = self.goal_yz
            pts = np.c_[np.full(len(g), self.plane_x), g]
            rec.log("world/plane/goals", rr.Points3D(pts, radii=0.008, colors=GREY), static=True)
        for name, label in (("q_cmd", "cmd"), ("q_meas", "meas"), ("qd_cmd", "qd cmd")):
            names = [f"joint_{i + 1} {label}" for i in range(6)]
            rec.log(f"joints/{name}", rr.SeriesLines(names=names), static=True)

    def raw(self, t: float, p: np.ndarray) -> None:
        """A detection as received, in base [m]."""
        self._at(t)
        self.raw_trail.append(np.asarray(p, dtype=float))
        pts = np.array(self.raw_trail)
        self.rec.log("world/detections/raw", self.rr.Points3D(pts, radii=0.006, colors=GREY))

    def accepted(self, t: float, p: np.ndarray) -> None:
        """A detection the intake accepted, in base [m]."""
        self._at(t)
        self.acc_trail.append(np.asarray(p, dtype=float))
        pts = np.array(self.acc_trail)
        self.rec.log("world/detections/accepted", self.rr.Points3D(pts, radii=0.01, colors=GREEN))

    def belief(self, t: float, mean: np.ndarray, cov: np.ndarray) -> None:
        """Filter belief: mean [X Y Z Vx Vy Vz] (6,) [m, m/s], covariance (6, 6)."""
        rr = self.rr
        self._at(t)
        half, quat = ellipsoid(np.asarray(cov)[:3, :3])
        self.rec.log(
            "world/ball/mean",
            rr.Arrows3D(origins=[mean[:3]], vectors=[0.1 * np.asarray(mean[3:6])], colors=BLUE),
        )
        self.rec.log(
            "world/ball/covariance",
            rr.Ellipsoids3D(
                centers=[mean[:3]], half_sizes=[half], quaternions=[quat], colors=BLUE,
                fill_mode=rr.components.FillMode.Solid,
            ),
        )  # fmt: skip

    def crossing(self, t: float, o_mean: np.ndarray, o_cov: np.ndarray) -> None:
        """Predicted crossing (Y, Z, tau) (3,) [m, m, s] with covariance (3, 3)."""
        rr = self.rr
        self._at(t)
        half, quat = ellipsoid(plane_cov(np.asarray(o_cov)))
        centre = [self.plane_x, float(o_mean[0]), float(o_mean[1])]
        sd_tau = math.sqrt(max(float(o_cov[2, 2]), 0.0))
        self.rec.log(
            "world/plane/crossing",
            rr.Ellipsoids3D(
                centers=[centre], half_sizes=[half], quaternions=[quat], colors=ORANGE,
                labels=[f"in {o_mean[2]:.3f} ± {sd_tau:.3f} s"],
            ),
        )  # fmt: skip

    def decision(
        self, t: float, text: str, value: float | None, goal: int, path: np.ndarray | None
    ) -> None:
        """The chosen motion: its description, value, goal and shield path (K, 3) [m]."""
        rr = self.rr
        self._at(t)
        self.rec.log("plan/motion", rr.TextLog(text))
        if value is not None and math.isfinite(value):
            self.rec.log("plan/value", rr.Scalars(float(value)))
        if self.goal_yz is not None and 0 <= goal < len(self.goal_yz):
            p = [self.plane_x, *self.goal_yz[goal]]
            self.rec.log(
                "world/plane/chosen_goal",
                rr.Points3D([p], radii=0.025, colors=RED, labels=[f"goal {goal}"]),
            )
        if path is not None and len(path) > 1:
            self.rec.log("world/plan/shield_path", rr.LineStrips3D([path], colors=RED))

    def arm(self, t: float, which: str, q: np.ndarray) -> None:
        """The arm at joints ``q`` (6,) [rad]: ``which`` is ``commanded`` or ``measured``."""
        rr, kin = self.rr, self.kin
        self._at(t)
        kin.update(q)
        pts = np.array([kin.placement(f)[:3, 3] for f in self.frames])
        colour = BLUE if which == "commanded" else GREEN
        self.rec.log(
            f"world/arm/{which}",
            rr.LineStrips3D([pts], colors=colour, radii=0.02 if which == "measured" else 0.012),
        )
        m = kin.placement(self.robot.shield_link)
        self.rec.log(
            f"world/arm/{which}/shield",
            rr.Cylinders3D(
                lengths=[max(self.robot.shield_thickness, 0.005)], radii=[self.robot.shield_radius],
                centers=[m[:3, 3]], quaternions=[matrix_quat(m[:3, :3])], colors=colour,
            ),
        )  # fmt: skip

    def joints(self, t: float, q_cmd, qd_cmd, q_meas) -> None:
        """Joint timelines: commanded positions [rad] and velocities [rad/s], measured positions
        (any may be None)."""
        self._at(t)
        for name, v in (("q_cmd", q_cmd), ("qd_cmd", qd_cmd), ("q_meas", q_meas)):
            if v is not None:
                self.rec.log(f"joints/{name}", self.rr.Scalars(np.asarray(v, dtype=float)))

    def event(self, t: float, kind: str, detail: str) -> None:
        """One daemon event (kind and JSON detail)."""
        self._at(t)
        self.rec.log("events", self.rr.TextLog(f"{kind} {detail}"))

    def shield_path(self, q123: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """Shield centres (K, 3) [m] for joints 1-3 samples (K, 3) with the wrist held."""
        out = np.empty((len(q123), 3))
        for i, q in enumerate(q123):
            out[i] = self.kin.shield(np.r_[q, wrist]).centre
        return out

    def close(self) -> None:
        """Flush and close the stream (a saved file is complete afterwards)."""
        self.rec.flush()
        self.rec.disconnect()


# ------------------------------------------------------------------ daemon side
class _Seen(NamedTuple):
    """What :meth:`DaemonView.on_detection` keeps (references to immutable objects only)."""

    t: float
    payload: bytes
    accepted: object  # control.intake.Accepted or None
    belief: object  # estimate.filter.Belief
    mode: str
    value: tuple[float, int] | None
    segment: object  # control.segments.Segment
    wrist: np.ndarray


class DaemonView:
    """The daemon's live view (module doc): queue at detection time, log in idle time.

    Args:
        painter: the painter of the stream.
        cfg: the run configuration (camera extrinsic, detection limits, gravity).
        tree_view: the runtime tree (goal joints for the chosen goal).
        joint_rate: joint samples logged per second at most [Hz].
        queue: jobs kept at most; older ones are dropped (counted) when the view falls behind.
    """

    def __init__(self, painter: Painter, cfg, tree_view, joint_rate: float = 50.0, queue=512):
        from thinkfast.contract.detection import parse_detection
        from thinkfast.contract.frames import to_base

        self.painter, self.cfg, self.tree = painter, cfg, tree_view
        self.period = 1.0 / joint_rate
        self.jobs: collections.deque = collections.deque()
        self.max_jobs = queue
        self.dropped = 0
        self.steps: collections.deque = collections.deque()  # (kind, callable) of the job
        self.done = 0  # steps run
        self.waited = 0  # times a step waited: its cost exceeded the time left in the cycle
        self.cost: dict[str, float] = {}  # s per kind of step, decaying maxima
        self.next_joints = -math.inf
        self._parse, self._to_base = parse_detection, to_base
        self._R, self._p = cfg.camera.rotation(), cfg.camera.translation()
        self._last_motion: tuple | None = None

    def on_detection(self, now: float, payload: bytes, accepted, executor) -> None:
        """Queue one detection and the executor's state after it (references only: cheap)."""
        ex = executor
        seen = _Seen(
            now, payload, accepted, ex.belief, str(ex.mode), ex.current_value(), ex.segment,
            ex.wrist.state[:3].copy(),
        )  # fmt: skip
        if len(self.jobs) >= self.max_jobs:
            self.jobs.popleft()
            self.dropped += 1
        self.jobs.append(seen)

    def service(self, now: float, t_joints: float, control, budget: float = math.inf) -> None:
        """One step of the view that is expected to end within ``budget`` [s].

        A job (the joints when due, ``t_joints`` being the time of the last EGM packet [s],
        else the oldest queued detection) is cut into steps of one or two log calls each. Each
        kind of step keeps the decaying maximum of its measured durations (``cost``); a step
        whose cost exceeds the budget waits, and its cost decays while it waits
        (``WAIT_DECAY``: halved after about 1400 waits, a second or two), so that one slow run
        (a cold start) does not keep it waiting for good; an unbounded budget (the controller
        silent) runs every step."""
        if not self.steps:
            if now >= self.next_joints and control.last is not None:
                self.next_joints = now + self.period
                self._joints(t_joints, control)
            elif self.jobs:
                self._detection(self.jobs.popleft())
            else:
                return
        kind, fn = self.steps[0]
        cost = self.cost.get(kind, INITIAL_COST)
        if cost > budget:
            self.cost[kind] = cost * WAIT_DECAY
            self.waited += 1
            return
        self.steps.popleft()
        t0 = time.perf_counter()
        fn()
        self.cost[kind] = max(time.perf_counter() - t0, 0.99 * cost)
        self.done += 1

    def _joints(self, t: float, control) -> None:
        p, last = self.painter, control.last
        meas = control.measured
        q_meas = None if meas is None else meas[1]
        q, qd = last.q, last.qd
        steps = self.steps
        steps.append(("timelines", lambda: p.joints(t, q, qd, q_meas)))
        steps.append(("arm", lambda: p.arm(t, "commanded", q)))
        if q_meas is not None:
            steps.append(("arm", lambda: p.arm(t, "measured", q_meas)))

    def _detection(self, s: _Seen) -> None:
        self.steps.append(("points", lambda: self._points(s)))
        b = s.belief
        if s.accepted is None or b.n_meas < 2:
            return
        self.steps.append(("belief", lambda: self.painter.belief(s.t, b.mean, b.cov)))
        self.steps.append(("crossing", lambda: self._crossing(s)))
        self.steps.append(("motion", lambda: self._motion(s)))

    def _points(self, s: _Seen) -> None:
        p = self.painter
        det = self._parse(s.payload, self.cfg.detections)
        if hasattr(det, "position"):
            p.raw(s.t, self._to_base(det, self._R, self._p).position)
        if s.accepted is not None:
            p.accepted(s.t, s.accepted.position)

    def _crossing(self, s: _Seen) -> None:
        b = s.belief
        c = self.tree.crossing(b.mean, b.cov, self.cfg.filter.gravity)
        if c.ok:
            self.painter.crossing(s.t, c.mean, c.cov)

    def _motion(self, s: _Seen) -> None:
        """The chosen motion, logged when it (or its value) changed."""
        seg = s.segment
        value, goal = (None, -1) if s.value is None else s.value
        if seg.kind == "steer":
            goal = seg.ref
        elif seg.kind == "terminal":
            goal = int(self.tree.tree.term_goal[seg.ref])
        key = (seg.kind, seg.t0, seg.ref, value)
        if key == self._last_motion:
            return
        self._last_motion = key
        path = None
        if seg.traj is not None:
            span = min(seg.duration, seg.traj.duration)
            ts = seg.t0 + np.linspace(0.0, span, PATH_SAMPLES)
            path = self.painter.shield_path(np.array([seg.state(t)[:3] for t in ts]), s.wrist)
        text = f"{s.mode}: {motion_text(seg.kind, seg.ref, goal, value)}"
        self.painter.decision(s.t, text, value, goal, path)

    def as_dict(self) -> dict:
        """Status block: steps run, waited for time, jobs dropped and queued, cost of each
        kind of step [ms]."""
        return {
            "done": self.done,
            "waited": self.waited,
            "dropped": self.dropped,
            "queued": len(self.jobs) + len(self.steps),
            "cost_ms": {k: round(1e3 * v, 3) for k, v in self.cost.items()},
        }

    def close(self) -> None:
        """Log what is still queued, then flush and close the stream."""
        while self.jobs:
            self._detection(self.jobs.popleft())
        while self.steps:
            self.steps.popleft()[1]()
        self.painter.close()


def daemon_view(text: str, robot, tree_view, cfg, joint_rate: float = 50.0) -> DaemonView:
    """The daemon's view for the ``--rerun`` option ``text`` (:func:`parse_sink`)."""
    sink = parse_sink(text)
    rec = open_stream(sink, f"thinkfast-run {time.strftime('%Y-%m-%d %H:%M:%S')}")
    painter = Painter(rec, robot, tree_view.plane_x, tree_view.goal_yz)
    return DaemonView(painter, cfg, tree_view, joint_rate)
