"""Live view in Foxglove (``thinkfast-run --foxglove [HOST:]PORT``): the Foxglove SDK's
WebSocket server in the daemon, fed between EGM replies under the same per-cycle budget as the
Rerun view (:class:`~thinkfast.daemon.live_view.DaemonView`): a step runs only when its measured
cost fits the time left before the next EGM packet.

Channels (log time = the daemon's time of the sample [ns since the epoch]; frame ``base``):

* ``/thinkfast/joints`` (JSON): ``t``, ``q_cmd``, ``qd_cmd``, ``q_meas`` [rad, rad/s], at most
  50 per second;
* ``/thinkfast/detections`` (JSON): ``t``, ``accepted``, ``position`` [m] (in base), ``belief``
  mean [m];
* ``/thinkfast/scene`` (``foxglove.SceneUpdate``): the arm at the commanded (blue) and measured
  (green) joints, link frames joined by a line; the ball's belief (red sphere).

Needs the ``foxglove`` extra (``foxglove-sdk``); imported only with the option.
"""

from __future__ import annotations

import collections
import json
import logging
import math
import time

import numpy as np

from thinkfast.daemon.live_view import INITIAL_COST, WAIT_DECAY
from thinkfast.errors import ConfigError

log = logging.getLogger("thinkfast.run")
JOINTS_SCHEMA = {
    "type": "object",
    "properties": {k: {"type": ["array", "null"], "items": {"type": "number"}}
                   for k in ("q_cmd", "qd_cmd", "q_meas")} | {"t": {"type": "number"}},
}  # fmt: skip
DETECTIONS_SCHEMA = {
    "type": "object",
    "properties": {
        "t": {"type": "number"},
        "accepted": {"type": "boolean"},
        "position": {"type": ["array", "null"], "items": {"type": "number"}},
        "belief": {"type": ["array", "null"], "items": {"type": "number"}},
    },
}
BACKLOG = 4096  # messages queued per client before a slow one is dropped (the SDK's policy)
COLOURS = {"commanded": (0.2, 0.4, 1.0), "measured": (0.2, 0.8, 0.3), "ball": (0.9, 0.2, 0.2)}


def parse_hostport(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); the host defaults to 127.0.0.1 (loopback)."""
    host, _, port = text.rpartition(":")
    try:
        n = int(port)
    except ValueError:
        n = -1
    if not 0 <= n <= 65535:
        raise ConfigError("--foxglove", None, f"{text!r}: expected [HOST:]PORT")
    return host or "127.0.0.1", n


class FoxgloveView:
    """The daemon's Foxglove server and channels (module doc); the daemon calls
    :meth:`on_detection` and :meth:`service` as it does for the Rerun view."""

    def __init__(self, host: str, port: int, robot, joint_rate: float = 50.0, queue: int = 512):
        try:
            import foxglove
            from foxglove import messages
            from foxglove.channels import SceneUpdateChannel
        except ImportError:
            raise ConfigError("--foxglove", None, "needs foxglove-sdk: pip install "
                              "'thinkfast[foxglove]'") from None  # fmt: skip
        from thinkfast.robot.kinematics import Kinematics

        self.m, self.robot = messages, robot
        self.server = foxglove.start_server(
            name="thinkfast-run", host=host, port=port, message_backlog_size=BACKLOG
        )
        self.joints_ch = foxglove.Channel("/thinkfast/joints", schema=JOINTS_SCHEMA,
                                          message_encoding="json")  # fmt: skip
        self.det_ch = foxglove.Channel("/thinkfast/detections", schema=DETECTIONS_SCHEMA,
                                       message_encoding="json")  # fmt: skip
        self.scene_ch = SceneUpdateChannel("/thinkfast/scene")
        self.kin = Kinematics(robot)
        self.frames = ["base_link"] + [j.child for j in robot.chain]
        self.period, self.next_joints = 1.0 / joint_rate, -math.inf
        self.jobs: collections.deque = collections.deque()
        self.max_jobs, self.dropped, self.done, self.waited = queue, 0, 0, 0
        self.cost: dict[str, float] = {}
        self.errors = 0

    @property
    def port(self) -> int:
        return self.server.port

    def on_detection(self, now: float, payload: bytes, accepted, executor) -> None:
        """Queue one detection with the belief after it (references only)."""
        b = executor.belief
        mean = None if b is None or b.n_meas < 1 else np.asarray(b.mean[:3], dtype=float)
        pos = None if accepted is None else np.asarray(accepted.position, dtype=float)
        if len(self.jobs) >= self.max_jobs:
            self.jobs.popleft()
            self.dropped += 1
        self.jobs.append((now, pos, mean))

    def service(self, now: float, t_joints: float, control, budget: float = math.inf) -> None:
        """One step (the joints when due, else the oldest detection) if its cost fits."""
        if now >= self.next_joints and control.last is not None:
            kind = "joints"
        elif self.jobs:
            kind = "detection"
        else:
            return
        cost = self.cost.get(kind, INITIAL_COST)
        if cost > budget:
            self.cost[kind] = cost * WAIT_DECAY
            self.waited += 1
            return
        t0 = time.perf_counter()
        if kind == "joints":
            self.next_joints = now + self.period
            meas = control.measured
            self._joints(
                t_joints, control.last.q, control.last.qd, None if meas is None else meas[1]
            )
        else:
            self._detection(*self.jobs.popleft())
        self.cost[kind] = max(time.perf_counter() - t0, 0.99 * cost)
        self.done += 1

    def _joints(self, t: float, q, qd, q_meas) -> None:
        ns = int(t * 1e9)
        msg = {"t": t, "q_cmd": _list(q), "qd_cmd": _list(qd), "q_meas": _list(q_meas)}
        self.joints_ch.log(json.dumps(msg).encode(), log_time=ns)
        arms = [self._arm("commanded", q)] + (
            [] if q_meas is None else [self._arm("measured", q_meas)]
        )
        self.scene_ch.log(self.m.SceneUpdate(entities=arms), log_time=ns)

    def _detection(self, t: float, pos, mean) -> None:
        ns = int(t * 1e9)
        msg = {"t": t, "accepted": pos is not None, "position": _list(pos), "belief": _list(mean)}
        self.det_ch.log(json.dumps(msg).encode(), log_time=ns)
        if mean is not None:
            m = self.m
            centre = m.Vector3(x=mean[0], y=mean[1], z=mean[2])
            ball = m.SpherePrimitive(
                pose=m.Pose(position=centre, orientation=m.Quaternion(w=1.0)),
                size=m.Vector3(x=0.067, y=0.067, z=0.067),
                color=m.Color(r=0.9, g=0.2, b=0.2, a=1.0),
            )
            ent = m.SceneEntity(frame_id="base", id="ball", spheres=[ball])
            self.scene_ch.log(m.SceneUpdate(entities=[ent]), log_time=ns)

    def _arm(self, which: str, q):
        m, kin = self.m, self.kin
        kin.update(np.asarray(q, dtype=float))
        pts = [m.Point3(x=p[0], y=p[1], z=p[2]) for p in
               (kin.placement(f)[:3, 3] for f in self.frames)]  # fmt: skip
        r, g, b = COLOURS[which]
        line = m.LinePrimitive(type=m.LinePrimitiveLineType.LineStrip, points=pts,
                               thickness=0.02, color=m.Color(r=r, g=g, b=b, a=1.0))  # fmt: skip
        return m.SceneEntity(frame_id="base", id=f"arm_{which}", lines=[line])

    def as_dict(self) -> dict:
        """Status block (the keys of the Rerun view's, docs/schemas/status.schema.json)."""
        return {"done": self.done, "waited": self.waited, "dropped": self.dropped,
                "queued": len(self.jobs), "errors": self.errors, "cost_ms": {k: round(1e3 * v, 3)
                                                      for k, v in self.cost.items()}}  # fmt: skip

    def close(self) -> None:
        self.server.stop()


def _list(v) -> list[float] | None:
    return None if v is None else [float(x) for x in np.asarray(v, dtype=float).reshape(-1)]
