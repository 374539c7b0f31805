"""Forward kinematics and Jacobians on the Pinocchio model.

Frames are resolved by name once; every function takes joint angles ``q`` [rad], shape (6,).
The shield pose is what the planner cares about: its centre [m] and its normal (unit vector), both
in ``base``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pinocchio as pin

from thinkfast.robot import fixed_order as fo
from thinkfast.robot.model import Robot


class ShieldPose(NamedTuple):
    """Shield disk in ``base``: centre [m] (3,), unit normal (3,)."""

    centre: np.ndarray
    normal: np.ndarray


class Kinematics:
    """FK of named frames for one robot; owns its Pinocchio ``data`` (not thread-safe).

    Args:
        robot: the loaded robot.
    """

    def __init__(self, robot: Robot):
        self.robot = robot
        self.model = robot.model
        self.data = self.model.createData()
        self._ids: dict[str, int] = {}
        self.shield_id = self.frame_id(robot.shield_link)

    def frame_id(self, name: str) -> int:
        """Pinocchio frame index of ``name``; raises KeyError listing valid names."""
        if name not in self._ids:
            if not self.model.existFrame(name):
                valid = sorted({f.name for f in self.model.frames})
                raise KeyError(f"unknown frame {name!r} (valid: {', '.join(valid)})")
            self._ids[name] = self.model.getFrameId(name)
        return self._ids[name]

    def update(self, q: np.ndarray) -> None:
        """Compute all frame placements for ``q`` [rad] (6,)."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=np.float64))

    def placement(self, name: str) -> np.ndarray:
        """Pose (4, 4) of frame ``name`` in ``base`` after :meth:`update`."""
        return self.data.oMf[self.frame_id(name)].homogeneous

    def fk(self, q: np.ndarray, name: str) -> np.ndarray:
        """Pose (4, 4) of frame ``name`` in ``base`` at ``q`` [rad] (6,)."""
        self.update(q)
        return self.placement(name)

    def shield(self, q: np.ndarray) -> ShieldPose:
        """Shield centre [m] and normal in ``base`` at ``q``."""
        self.update(q)
        M = self.data.oMf[self.shield_id]
        return ShieldPose(M.translation.copy(), M.rotation[:, 2].copy())

    def shield_jacobian(self, q: np.ndarray) -> tuple[ShieldPose, np.ndarray, np.ndarray]:
        """Shield pose and Jacobians of its centre (3, 6) and normal (3, 6) w.r.t. ``q``."""
        q = np.asarray(q, dtype=np.float64)
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(
            self.model, self.data, self.shield_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        M = self.data.oMf[self.shield_id]
        n = M.rotation[:, 2].copy()
        Jn = -fo.matmul(pin.skew(n), J[3:])  # d n / dt = omega x n
        return ShieldPose(M.translation.copy(), n), J[:3].copy(), Jn
