"""The frames of the contract: ``camera`` posed in ``base`` by the camera extrinsic.

Both frames follow REP-103 (x forward, y left, z up; metres); see docs/INTERFACES.md, "Frames".
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from thinkfast.config import spec
from thinkfast.contract.detection import Detection, _frozen


@dataclasses.dataclass(frozen=True)
class CameraExtrinsic:
    """Pose of the ``camera`` frame in ``base`` (``T_base_camera``).

    Default cell (ASSUMPTION until the cell is measured): the ZED 2i sits at the robot base on
    the camera pedestal of robots/irb1600/robot.toml (box x 0.40..0.52 m, top at z 0.25 m), lens
    at (0.46, 0, 0.30) m, level and looking +x (the same way as the base, towards the thrower).
    ``rpy`` is fixed-axis roll-pitch-yaw as in URDF: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
    """

    xyz: tuple[float, float, float] = spec(
        (0.46, 0.0, 0.30),
        doc="camera origin in base (ASSUMED default cell: lens on the pedestal at the robot base); "
        "metres, within 20 m of the base, so that millimetres are refused",
        unit="m",
        length=3,
        lo=-20.0,
        hi=20.0,
    )
    rpy: tuple[float, float, float] = spec(
        (0.0, 0.0, 0.0),
        doc="camera orientation in base (roll, pitch, yaw), radians: within half a turn, so "
        "that degrees are refused",
        unit="rad",
        length=3,
        lo=-math.pi,
        hi=math.pi,
    )

    def rotation(self) -> np.ndarray:
        """``R_base_camera``, shape (3, 3), read-only."""
        return rotation_from_rpy(self.rpy)

    def translation(self) -> np.ndarray:
        """``p_base_camera`` [m], shape (3,), read-only."""
        p = np.array(self.xyz, dtype=float)
        p.setflags(write=False)
        return p


def rotation_from_rpy(rpy) -> np.ndarray:
    """Fixed-axis roll, pitch, yaw [rad] -> rotation matrix ``Rz @ Ry @ Rx``, shape (3, 3)."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    R = np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
    return _frozen(R)


def to_base(det: Detection, R_base_camera: np.ndarray, p_base_camera: np.ndarray) -> Detection:
    """Express a detection in ``base``: ``p_base = R p_cam + t``, ``C_base = R C_cam R^T``.

    Args:
        det: an accepted detection; returned unchanged if already in ``base``.
        R_base_camera: rotation, shape (3, 3) (e.g. :meth:`CameraExtrinsic.rotation`).
        p_base_camera: camera origin in base [m], shape (3,).

    Returns:
        The same detection with ``frame="base"``.
    """
    if det.frame == "base":
        return det
    pos = _frozen(R_base_camera @ det.position + p_base_camera)
    cov = None
    if det.covariance is not None:
        cov = _frozen(R_base_camera @ det.covariance @ R_base_camera.T)
    return det._replace(position=pos, frame="base", covariance=cov)


POSE_KEYS = ("yaw", "offset", "base_height")  # PlanePose's pose, beside its distance


@dataclasses.dataclass(frozen=True)
class PlanePose:
    """Where the intercept plane stands in ``base``, and the ``plane`` frame it defines.

    The ``plane`` frame (REP-103 too): x along the plane's normal towards the thrower, y along
    the plane, z up, origin on the floor; the plane is ``x = distance``. A point ``p`` of
    ``base`` is, in ``plane``, ``Rz(-yaw) p + (0, -offset, base_height)``: the plane's normal
    is ``(cos yaw, sin yaw, 0)`` in ``base``, its centre line ``y = 0`` passes ``offset`` to the
    left of the base's axis, and heights are above the floor. With no pose (yaw, offset and
    base height zero) ``plane`` is ``base`` and ``distance`` means what the contract says
    (docs/INTERFACES.md, "Frames"). Inside a run every position is in ``plane``: the belief,
    the crossing (Y, Z), the protected region, the thrower and the judge; the robot's forward
    kinematics is placed there (``Robot.placed``), the cameras' extrinsics stay in ``base``.
    """

    distance: float = 0.8  # m: the plane is x = distance in ``plane``
    yaw: float = 0.0  # rad: the plane's normal turned about base z
    offset: float = 0.0  # m: the plane's centre line, to the left of the base's axis
    base_height: float = 0.0  # m: the base's origin above the floor

    @classmethod
    def from_dict(cls, d) -> PlanePose:
        """The pose of a ``{"distance", "yaw", "offset", "base_height"}`` mapping (a tree's
        ``parameters.plane``, a record's ``plane``); a pose key left out is 0.

        Raises:
            KeyError: no ``distance``. TypeError, ValueError: a value that is not a number.
        """
        return cls(float(d["distance"]), *(float(d.get(k, 0.0)) for k in POSE_KEYS))

    def as_dict(self) -> dict[str, float]:
        """``{"distance", "yaw", "offset", "base_height"}`` [m, rad], in that order."""
        return {"distance": float(self.distance), **{k: float(getattr(self, k)) for k in POSE_KEYS}}

    @property
    def identity(self) -> bool:
        """True where ``plane`` is ``base`` (no pose): nothing is transformed, bit for bit."""
        return self.yaw == 0.0 and self.offset == 0.0 and self.base_height == 0.0

    def rotation(self) -> np.ndarray:
        """``R_plane_base`` (3, 3): ``Rz(-yaw)``, read-only."""
        return rotation_from_rpy((0.0, 0.0, -self.yaw))

    def translation(self) -> np.ndarray:
        """``p_plane_base`` [m] (3,): the base's origin in ``plane``, read-only."""
        return _frozen(np.array([0.0, -self.offset, self.base_height]))

    def matrix(self) -> np.ndarray:
        """``T_plane_base`` (4, 4), read-only."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation(), self.translation()
        return _frozen(T)

    def to_plane(self, p_base: np.ndarray) -> np.ndarray:
        """Points [m] (..., 3) of ``base`` in ``plane`` (returned as given when no pose)."""
        p = np.asarray(p_base, dtype=float)
        if self.identity:
            return p
        R, t = self.rotation(), self.translation()
        return p @ R.T + t

    def to_base(self, p_plane: np.ndarray) -> np.ndarray:
        """Points [m] (..., 3) of ``plane`` in ``base`` (returned as given when no pose)."""
        p = np.asarray(p_plane, dtype=float)
        if self.identity:
            return p
        R, t = self.rotation(), self.translation()
        return (p - t) @ R

    def camera(self, extrinsic: CameraExtrinsic) -> CameraExtrinsic:
        """A camera's pose in ``plane`` from its extrinsic in ``base`` (the same one when no
        pose): ``T_plane_camera = T_plane_base T_base_camera``."""
        if self.identity:
            return extrinsic
        roll, pitch, yaw = extrinsic.rpy
        turned = math.remainder(yaw - self.yaw, math.tau)  # Rz(-a) Rz(y) Ry Rx = Rz(y - a) Ry Rx
        xyz = self.to_plane(np.array(extrinsic.xyz, dtype=float))
        return dataclasses.replace(
            extrinsic, xyz=tuple(float(v) for v in xyz), rpy=(roll, pitch, turned)
        )
