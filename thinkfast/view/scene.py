"""The 3D scene of the live views and of the exports: pure geometry and Foxglove's SceneUpdate.

* Geometry (pure): :func:`ellipsoid` (half-axes and orientation of a covariance's
  ``ELLIPSOID_SIGMAS`` ellipsoid), :func:`matrix_quat`, :func:`plane_cov` (the crossing Gaussian
  flat on the plane). Drawn by the Rerun painter (:mod:`thinkfast.view.rerun_painter`) and by
  :class:`Scene`.
* :class:`Scene`: the same quantities as ``foxglove.SceneEntity`` objects (frame ``base``) on the
  topic :data:`SCENE_TOPIC`, one entity id per quantity (:data:`ENTITY_IDS`): a later update of
  an id replaces the earlier one. The live Foxglove view (``thinkfast-run --foxglove``) and the
  MCAP export (``thinkfast-sim record mcap``) log the same entities with the same schema
  (``foxglove.SceneUpdate``, protobuf), so a Foxglove layout made live opens a record too.

``foxglove-sdk`` (the ``foxglove`` extra) is imported when a :class:`Scene` is made.
"""

from __future__ import annotations

import math

import numpy as np

ELLIPSOID_SIGMAS = 2.0  # half-axes of the belief and crossing ellipsoids, in standard deviations
SCENE_TOPIC = "/thinkfast/scene"
FRAME = "base"
BALL_DIAMETER = 0.067  # m, a tennis ball: the size the ball's mean is drawn at (display only)
ENTITY_IDS = {
    "goals": "goal grid on the blocking plane (grey)",
    "arm_commanded": "arm at the commanded joints (blue line through the joint frames, shield)",
    "arm_measured": "arm at the measured joints (green line through the joint frames, shield)",
    "ball": "filter belief: mean (red ball), velocity arrow (0.1 s), 2-sigma position ellipsoid",
    "crossing": "predicted crossing Gaussian on the plane, 2 sigma (orange), time to crossing",
    "plan": "the chosen motion: shield centre along it (red line), chosen goal, text",
}
COLOURS = {  # r, g, b, a
    "grey": (0.6, 0.6, 0.6, 1.0),
    "commanded": (0.24, 0.55, 1.0, 1.0),
    "measured": (0.16, 0.78, 0.31, 1.0),
    "ball": (0.9, 0.2, 0.2, 1.0),
    "cov": (0.24, 0.55, 1.0, 0.35),
    "crossing": (1.0, 0.59, 0.12, 0.6),
    "plan": (0.9, 0.2, 0.2, 1.0),
}


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
    """Quaternion (x, y, z, w) of a rotation matrix (3, 3) (Pinocchio's: about a hundred times
    faster than scipy's, which took most of a live view's arm step)."""
    import pinocchio

    return np.array(pinocchio.Quaternion(np.array(r, dtype=float)).coeffs())


def plane_cov(o_cov: np.ndarray, thickness: float = 1e-6) -> np.ndarray:
    """3x3 covariance [m^2] in base of the crossing point on the plane x = const, from the
    crossing covariance (Y, Z, tau) (3, 3): flat along x."""
    c = np.zeros((3, 3))
    c[1:, 1:] = o_cov[:2, :2]
    c[0, 0] = thickness
    return c


def scene_schema():
    """The ``foxglove.SceneUpdate`` schema (name, encoding ``protobuf``, FileDescriptorSet)."""
    from foxglove.messages import SceneUpdate

    return SceneUpdate.get_schema()


# ------------------------------------------------------------------ Foxglove entities
class Scene:
    """thinkfast's quantities as Foxglove scene entities (:data:`ENTITY_IDS`).

    Args:
        robot: the robot (joint frames, shield link and size).
        plane_x: the blocking plane's distance [m] (x in base).
        goal_yz: goal grid (G, 2) [m] on the plane, or None when unknown.
    """

    def __init__(self, robot, plane_x: float, goal_yz: np.ndarray | None):
        from foxglove import messages

        from thinkfast.robot.kinematics import Kinematics

        self.m, self.robot = messages, robot
        self.kin = Kinematics(robot)
        self.plane_x = float(plane_x)
        self.goal_yz = None if goal_yz is None else np.asarray(goal_yz, dtype=float)
        self.frames = ["base_link"] + [j.child for j in robot.chain]

    def update(self, entities: list) -> bytes:
        """One ``SceneUpdate`` of ``entities``, protobuf-encoded."""
        return self.m.SceneUpdate(entities=entities).encode()

    def goals(self):
        """The goal grid as small spheres on the plane, or None without a grid."""
        if self.goal_yz is None or not len(self.goal_yz):
            return None
        s = [self._sphere((self.plane_x, y, z), (0.016,) * 3, "grey") for y, z in self.goal_yz]
        return self._entity("goals", spheres=s)

    def arm(self, which: str, q: np.ndarray):
        """The arm at joints ``q`` (6,) [rad]; ``which``: ``commanded`` or ``measured``."""
        m, kin, robot = self.m, self.kin, self.robot
        kin.update(np.asarray(q, dtype=float))
        pts = [self._point(kin.placement(f)[:3, 3]) for f in self.frames]
        line = m.LinePrimitive(type=m.LinePrimitiveLineType.LineStrip, points=pts,
                               thickness=0.02, color=self._colour(which))  # fmt: skip
        s = kin.placement(robot.shield_link)
        d = 2.0 * robot.shield_radius
        shield = m.CylinderPrimitive(
            pose=self._pose(s[:3, 3], matrix_quat(s[:3, :3])),
            size=m.Vector3(x=d, y=d, z=max(robot.shield_thickness, 0.005)),
            bottom_scale=1.0, top_scale=1.0, color=self._colour(which),
        )  # fmt: skip
        return self._entity(f"arm_{which}", lines=[line], cylinders=[shield])

    def ball(self, mean: np.ndarray, cov: np.ndarray):
        """Filter belief: mean [X Y Z Vx Vy Vz] (6,) [m, m/s], covariance (6, 6)."""
        m = self.m
        mean, cov = np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)
        half, quat = ellipsoid(cov[:3, :3])
        spheres = [
            self._sphere(mean[:3], (BALL_DIAMETER,) * 3, "ball"),
            self._sphere(mean[:3], 2.0 * half, "cov", quat),
        ]
        v = mean[3:6]
        speed = float(np.linalg.norm(v))
        arrows = []
        if speed > 1e-6:  # 0.1 s of flight, pointing along the velocity (the arrow's +x)
            arrows.append(m.ArrowPrimitive(
                pose=self._pose(mean[:3], _quat_from_x(v / speed)), shaft_length=0.08 * speed,
                shaft_diameter=0.01, head_length=0.02 * speed, head_diameter=0.03,
                color=self._colour("ball"),
            ))  # fmt: skip
        return self._entity("ball", spheres=spheres, arrows=arrows)

    def crossing(self, o_mean: np.ndarray, o_cov: np.ndarray):
        """Predicted crossing (Y, Z, tau) (3,) [m, m, s] with covariance (3, 3) [m^2, s^2]."""
        m = self.m
        o_cov = np.asarray(o_cov, dtype=float)
        half, quat = ellipsoid(plane_cov(o_cov))
        centre = (self.plane_x, float(o_mean[0]), float(o_mean[1]))
        sd_tau = math.sqrt(max(float(o_cov[2, 2]), 0.0))
        text = m.TextPrimitive(
            pose=self._pose(np.add(centre, (0.0, 0.0, 0.15))), billboard=True, font_size=14.0,
            scale_invariant=True, color=self._colour("crossing"),
            text=f"in {float(o_mean[2]):.3f} ± {sd_tau:.3f} s",
        )  # fmt: skip
        sphere = self._sphere(centre, np.maximum(2.0 * half, 0.002), "crossing", quat)
        return self._entity("crossing", spheres=[sphere], texts=[text])

    def plan(self, text: str, goal: int, path: np.ndarray | None):
        """The chosen motion: its text, goal (index in the grid, -1 none), shield path (K, 3)."""
        m = self.m
        lines, spheres = [], []
        if path is not None and len(path) > 1:
            pts = [self._point(p) for p in path]
            lines.append(m.LinePrimitive(type=m.LinePrimitiveLineType.LineStrip, points=pts,
                                         thickness=0.01, color=self._colour("plan")))  # fmt: skip
        at = (self.plane_x, 0.0, 2.0)
        if self.goal_yz is not None and 0 <= goal < len(self.goal_yz):
            at = (self.plane_x, *self.goal_yz[goal])
            spheres.append(self._sphere(at, (0.05,) * 3, "plan"))
        label = m.TextPrimitive(
            pose=self._pose(np.add(at, (0.0, 0.0, 0.12))), billboard=True, font_size=14.0,
            scale_invariant=True, color=self._colour("plan"), text=text,
        )  # fmt: skip
        return self._entity("plan", lines=lines, spheres=spheres, texts=[label])

    def shield_path(self, q123: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """Shield centres (K, 3) [m] for joints 1-3 samples (K, 3) with the wrist held."""
        out = np.empty((len(q123), 3))
        for i, q in enumerate(q123):
            out[i] = self.kin.shield(np.r_[q, wrist]).centre
        return out

    # -------------------------------------------------------------- message pieces
    def _entity(self, name: str, **primitives):
        return self.m.SceneEntity(frame_id=FRAME, id=name, **primitives)

    def _point(self, p):
        return self.m.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))

    def _pose(self, p, quat=(0.0, 0.0, 0.0, 1.0)):
        m = self.m
        x, y, z, w = (float(v) for v in quat)
        pos = m.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
        return m.Pose(position=pos, orientation=m.Quaternion(x=x, y=y, z=z, w=w))

    def _sphere(self, centre, size, colour: str, quat=(0.0, 0.0, 0.0, 1.0)):
        m = self.m
        sx, sy, sz = (float(v) for v in size)
        return m.SpherePrimitive(pose=self._pose(centre, quat), size=m.Vector3(x=sx, y=sy, z=sz),
                                 color=self._colour(colour))  # fmt: skip

    def _colour(self, name: str):
        r, g, b, a = COLOURS[name]
        return self.m.Color(r=r, g=g, b=b, a=a)


def _quat_from_x(u: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of the shortest rotation taking +x onto the unit vector ``u``."""
    c = float(u[0])  # x . u; x cross u = (0, -u_z, u_y)
    if c < -1.0 + 1e-9:  # opposite: half a turn about z
        return np.array([0.0, 0.0, 1.0, 0.0])
    q = np.array([0.0, -float(u[2]), float(u[1]), 1.0 + c])
    return q / np.linalg.norm(q)
