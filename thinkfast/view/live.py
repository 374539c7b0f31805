"""Live view with Rerun: what the daemon sees, believes, decides and commands (docs/LIVE_VIEW.md).

Three layers:

* :func:`parse_sink` / :func:`open_stream`: the ``--rerun`` option (``spawn``, ``connect[=URL]``,
  ``save=FILE.rrd``) and the Rerun recording stream it opens. ``rerun-sdk`` is optional (the
  ``view`` extra); it is imported only here, and only when the option is given.
* :class:`~thinkfast.view.rerun_painter.Painter` turns thinkfast's arrays into Rerun entities
  (:mod:`thinkfast.view.rerun_painter`).
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
import logging
import math
import time
from typing import NamedTuple

import numpy as np

from thinkfast.errors import ConfigError
from thinkfast.view.rerun_painter import Painter, motion_text

APP_ID = "thinkfast"
DEFAULT_CONNECT = "rerun+http://127.0.0.1:9876/proxy"
PATH_SAMPLES = 24  # shield positions drawn along the chosen motion
INITIAL_COST = 0.0015  # s: expected duration of a job before one of its kind was measured
WAIT_DECAY = 0.9995  # factor on a job kind's cost each time it waits for time
SINKS = ("spawn", "connect", "save")
STATUS_PERIOD = 0.5  # s between status messages drawn (the daemon publishes 20 a second)
log = logging.getLogger("thinkfast.run")


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
        painter: the painter of the stream (:class:`~thinkfast.view.rerun_painter.Painter`,
            or :class:`~thinkfast.view.channels.ChannelPainter` for Foxglove).
        cfg: the run configuration (camera extrinsic, detection limits, gravity).
        tree_view: the runtime tree (goal joints for the chosen goal).
        joint_rate: joint samples logged per second at most [Hz].
        queue: jobs kept at most; older ones are dropped (counted) when the view falls behind.
        plane: the robot's plane (``Robot.placement``): raw detections are drawn in its frame.
    """

    def __init__(
        self, painter: Painter, cfg, tree_view, joint_rate: float = 50.0, queue=512, plane=None
    ):
        from thinkfast.contract.detection import parse_detection
        from thinkfast.contract.frames import PlanePose, to_base

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
        # raw detections are in base on the wire; the view draws in the frame of the estimates
        self._plane = PlanePose() if plane is None else plane
        self._last_motion: tuple | None = None
        self.status_msg: dict | None = None  # the daemon's last status message, not yet drawn
        self.next_status = -math.inf
        self.errors = 0  # steps that raised (counted, the first logged): never into the daemon

    def on_status(self, now: float, msg: dict) -> None:
        """Keep the daemon's status message ``msg`` (a reference; drawn in :meth:`service`)."""
        self.status_msg = (now, msg)

    def on_detection(self, now: float, payload: bytes, out) -> None:
        """Queue one detection and the core's outcome of it (``out``:
        :class:`~thinkfast.control.outcome.DetectionOutcome`; references only: cheap)."""
        d = out.decision
        value = None if d is None else (d.value, d.goal)
        seen = _Seen(now, payload, out.detection, out.belief, out.mode, value, out.segment,
                     out.wrist)  # fmt: skip
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
            elif now >= self.next_status and self.status_msg is not None:
                self.next_status = now + STATUS_PERIOD
                t, msg = self.status_msg
                self.status_msg = None
                self.steps.append(("status", lambda: self.painter.status(t, msg)))
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
        try:
            fn()
        except Exception:  # a viewer's failure is the view's, never the daemon's
            self.errors += 1
            if self.errors == 1:
                log.exception("live view: a %s step failed (counted in status view.errors)", kind)
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
            p.raw(s.t, self._plane.to_plane(self._to_base(det, self._R, self._p).position))
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
        """Status block: steps run, waited for time, jobs dropped and queued, steps failed,
        cost of each kind of step [ms]."""
        return {
            "done": self.done,
            "waited": self.waited,
            "dropped": self.dropped,
            "queued": len(self.jobs) + len(self.steps),
            "errors": self.errors,
            "cost_ms": {k: round(1e3 * v, 3) for k, v in self.cost.items()},
        }

    def close(self) -> None:
        """Log what is still queued, then flush and close the stream."""
        while self.jobs:
            self._detection(self.jobs.popleft())
        while self.steps:
            try:
                self.steps.popleft()[1]()
            except Exception:
                self.errors += 1
        self.painter.close()


def daemon_view(text: str, robot, tree_view, cfg, joint_rate: float = 50.0) -> DaemonView:
    """The daemon's view for the ``--rerun`` option ``text`` (:func:`parse_sink`)."""
    sink = parse_sink(text)
    rec = open_stream(sink, f"thinkfast-run {time.strftime('%Y-%m-%d %H:%M:%S')}")
    painter = Painter(rec, robot, tree_view.plane_x, tree_view.goal_yz)
    return DaemonView(painter, cfg, tree_view, joint_rate, plane=robot.placement)
