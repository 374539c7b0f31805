"""The Rerun painter: thinkfast's arrays as Rerun entities (docs/LIVE_VIEW.md).

:class:`Painter` turns detections, the filter belief, the plane crossing, the decision and the
joints into the entities of :data:`ENTITIES` on the ``time`` timeline (Unix time [s]). Used by
the daemon live (:mod:`thinkfast.view.live`) and by ``thinkfast-sim replay --rerun``
offline (:mod:`thinkfast.view.record_rerun`). The geometry it draws is pure (ellipsoids,
quaternions, the crossing on the plane: :mod:`thinkfast.view.scene`, shared with the Foxglove
view). ``rerun`` is imported when a painter is made.
"""

from __future__ import annotations

import collections
import json
import math

import numpy as np

from thinkfast.view.scene import ELLIPSOID_SIGMAS, ellipsoid, matrix_quat, plane_cov

__all__ = ["ELLIPSOID_SIGMAS", "ENTITIES", "Painter", "ellipsoid", "matrix_quat", "plane_cov"]
TIMELINE = "time"  # Unix time [s]
TRAIL = 240  # detections kept in the raw and accepted trails (about 4 s at 60 Hz)

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
    "status": "the daemon's status message, as JSON (live only)",
}
GREY, GREEN, ORANGE, BLUE, RED = (
    (150, 150, 150),
    (40, 200, 80),
    (255, 150, 30),
    (60, 140, 255),
    (230, 50, 50),
)


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
        """A detection as received, in the plane's frame [m] (``base`` without a pose)."""
        self._at(t)
        self.raw_trail.append(np.asarray(p, dtype=float))
        pts = np.array(self.raw_trail)
        self.rec.log("world/detections/raw", self.rr.Points3D(pts, radii=0.006, colors=GREY))

    def accepted(self, t: float, p: np.ndarray) -> None:
        """A detection the intake accepted, in the plane's frame [m] (``base`` without a pose)."""
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

    def status(self, t: float, msg: dict) -> None:
        """The daemon's status message (docs/INTERFACES.md "Status")."""
        self._at(t)
        self.rec.log("status", self.rr.TextDocument(json.dumps(msg, indent=1)))

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
