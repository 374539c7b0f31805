"""Forward kinematics of many configurations at once, in numpy, from the URDF chain.

Pinocchio is the reference (``Kinematics``); this batched form poses a whole sampled primitive in
one pass for collision checking. The tests hold the two to 1e-12. Joint rotations about a frame
axis (x, y or z, as on the IRB 1600) update two columns in closed form; other axes use Rodrigues.
"""

from __future__ import annotations

import numpy as np

from thinkfast.robot import fixed_order as fo
from thinkfast.robot.model import Robot


def axis_rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) about a unit ``axis`` (3,) by ``angle`` [rad] (N,)."""
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    C = 1.0 - c
    R = np.empty((len(angle), 3, 3))
    R[:, 0, 0] = c + x * x * C
    R[:, 0, 1] = x * y * C - z * s
    R[:, 0, 2] = x * z * C + y * s
    R[:, 1, 0] = y * x * C + z * s
    R[:, 1, 1] = c + y * y * C
    R[:, 1, 2] = y * z * C - x * s
    R[:, 2, 0] = z * x * C - y * s
    R[:, 2, 1] = z * y * C + x * s
    R[:, 2, 2] = c + z * z * C
    return R


def _rotate_about_frame_axis(R: np.ndarray, k: int, sign: float, angle: np.ndarray) -> np.ndarray:
    """R @ Rot(sign * e_k, angle) for a batch R (N, 3, 3), by mixing the two other columns."""
    i, j = (k + 1) % 3, (k + 2) % 3
    c, s = np.cos(angle)[:, None], sign * np.sin(angle)[:, None]
    out = R.copy()
    out[:, :, i] = c * R[:, :, i] + s * R[:, :, j]
    out[:, :, j] = -s * R[:, :, i] + c * R[:, :, j]
    return out


class BatchFK:
    """Link poses in ``base`` for a batch of configurations.

    Args:
        robot: the robot (its URDF chain is used, parents first).
    """

    def __init__(self, robot: Robot):
        self.robot = robot
        self.root = next(link for link, parent in robot.link_parent.items() if not parent)
        self._steps = []
        for j in robot.chain:
            frame_axis = None
            if j.index >= 0:
                k = int(np.argmax(np.abs(j.axis)))
                if abs(abs(j.axis[k]) - 1.0) < 1e-12:
                    frame_axis = (k, float(np.sign(j.axis[k])))
            R0 = j.T_parent_joint[:3, :3]
            self._steps.append(
                (
                    j,
                    np.ascontiguousarray(R0),
                    j.T_parent_joint[:3, 3].copy(),
                    np.allclose(R0, np.eye(3)),
                    frame_axis,
                )
            )

    def link_poses(self, q: np.ndarray, until: str | None = None) -> dict[str, np.ndarray]:
        """Poses (N, 4, 4) of every link for joint angles ``q`` [rad] (N, 6).

        Args:
            q: joint angles, shape (N, 6) (or (6,) for one configuration).
            until: stop once this link is posed (its ancestors are returned too).
        """
        return assemble(*self.frames(q, until))

    def frames(
        self, q: np.ndarray, until: str | None = None, resume: tuple[dict, dict] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Rotations (N, 3, 3) and origins (N, 3) of the links, as :meth:`link_poses` poses them.

        Args:
            q: joint angles [rad] (N, 6).
            until: stop once this link is posed.
            resume: the frames of an earlier call on the same first joints (e.g. with ``until``),
                continued from there: the links they hold are not recomputed.
        """
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        n = len(q)
        if resume is None:
            rot = {self.root: np.broadcast_to(np.eye(3), (n, 3, 3))}
            pos = {self.root: np.zeros((n, 3))}
        else:
            rot, pos = dict(resume[0]), dict(resume[1])
        for j, R0, t0, identity, frame_axis in self._steps:
            if j.child in rot:
                if j.child == until:
                    break
                continue
            Rp = rot[j.parent]
            pos[j.child] = pos[j.parent] + fo.matvec(Rp, t0)
            R = Rp if identity else fo.matmul(Rp, R0)
            if j.index >= 0:
                if frame_axis is not None:
                    R = _rotate_about_frame_axis(R, frame_axis[0], frame_axis[1], q[:, j.index])
                else:
                    R = fo.matmul(R, axis_rotation(j.axis, q[:, j.index]))
            rot[j.child] = R
            if j.child == until:
                break
        return rot, pos


def assemble(rot: dict[str, np.ndarray], pos: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Poses (N, 4, 4) from the rotations (N, 3, 3) and origins (N, 3) of :meth:`BatchFK.frames`."""
    out = {}
    for link, R in rot.items():
        n = len(R)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = pos[link]
        T[:, 3, 3] = 1.0
        out[link] = T
    return out
