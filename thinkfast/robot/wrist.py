"""The coplanar wrist rule: joints 4-5 keep the shield normal along a given direction.

For the ABB x-y-x spherical wrist (joint_4 about x, joint_5 about y, joint_6 about x, all origins
without rotation) and a shield whose normal is link_6's x axis (tool0 = link_6 rotated pi/2 about
y), the normal is n = R_03 Rx(q4) Ry(q5) e_x. With v = R_03^T n = (cos q5, sin q4 sin q5,
-cos q4 sin q5): q5 = +-acos(v_x), q4 = atan2(v_y, -v_z) (+ pi on the other branch). joint_6 turns
the disk about its own axis and is held constant.

Along a path the solution is made continuous: the branch flips where the bend direction jumps by
more than pi/2 (passing near the singularity v = e_x, where the forearm is parallel to the normal),
q4 is unwrapped, and the start is the branch and 2 pi wrap nearest the previous wrist angles.
"""

from __future__ import annotations

import math

import numpy as np

from thinkfast.errors import RobotModelError
from thinkfast.robot import fixed_order as fo
from thinkfast.robot.batch_fk import BatchFK, assemble
from thinkfast.robot.model import Robot


def check_wrist_geometry(robot: Robot) -> None:
    """Raise RobotModelError unless the robot has the x-y-x wrist the rule is written for."""
    by_name = {j.name: j for j in robot.chain}
    want = {"joint_4": (1, 0, 0), "joint_5": (0, 1, 0), "joint_6": (1, 0, 0)}
    for name, axis in want.items():
        j = by_name.get(name)
        if (
            j is None
            or not np.allclose(j.axis, axis)
            or not np.allclose(j.T_parent_joint[:3, :3], np.eye(3))
        ):
            raise RobotModelError(f"coplanar wrist rule needs an x-y-x wrist; {name} differs")


class CoplanarWrist:
    """Wrist angles (joints 4-6) holding the shield normal along ``normal`` for given joints 1-3.

    Args:
        robot: the robot (x-y-x wrist checked).
        normal: shield normal in ``base`` (unit vector (3,)), default +x (facing the ball).
    """

    def __init__(self, robot: Robot, normal=(1.0, 0.0, 0.0)):
        check_wrist_geometry(robot)
        self.robot = robot
        self.fk = BatchFK(robot)
        n = np.asarray(normal, dtype=np.float64)
        self.normal = n / np.linalg.norm(n)
        self._arm = _arm_rotations(robot)

    def solve(
        self, q123: np.ndarray, q_prev: np.ndarray, normal: np.ndarray | None = None
    ) -> np.ndarray:
        """Wrist angles [rad] (N, 3) along a path of joints 1-3 [rad] (N, 3).

        Args:
            q123: joints 1-3 at consecutive samples of a continuous path.
            q_prev: wrist angles (3,) just before the first sample (for continuity).
            normal: shield normal in ``base`` for this call (unit (3,)); default: the
                constructor's.
        """
        n = self.normal if normal is None else np.asarray(normal, dtype=np.float64)
        q123 = np.atleast_2d(q123)
        q = np.zeros((len(q123), 6))
        q[:, :3] = q123
        R03 = self.fk.link_poses(q, until="link_3")["link_3"][:, :3, :3]
        v = np.einsum("nji,j->ni", R03, n)  # R03^T n
        q5 = fo.arccos(np.clip(v[:, 0], -1.0, 1.0))
        theta = fo.arctan2(v[:, 1], -v[:, 2])
        jump = np.abs(_wrapped(np.diff(theta)))
        sign = np.where(np.cumsum(np.r_[0, jump > 0.5 * np.pi]) % 2 == 0, 1.0, -1.0)
        q4 = theta + np.where(sign < 0, np.pi, 0.0)
        q5 = sign * q5
        # start on the branch nearest the previous wrist
        flipped_q4, flipped_q5 = q4[0] + np.pi, -q5[0]
        if _ang(flipped_q4 - q_prev[0]) + abs(flipped_q5 - q_prev[1]) < _ang(
            q4[0] - q_prev[0]
        ) + abs(q5[0] - q_prev[1]):
            q4, q5 = q4 + np.pi, -q5
        q4 = np.unwrap(q4)
        q4 += 2 * np.pi * np.round((q_prev[0] - q4[0]) / (2 * np.pi))
        return np.column_stack([q4, q5, np.full(len(q4), q_prev[2])])

    def solve_paths(
        self, q123: np.ndarray, starts: np.ndarray, q_prev: np.ndarray, frames=None
    ) -> np.ndarray:
        """:meth:`solve` of many paths at once (the constructor's normal), bit for bit.

        Args:
            q123: joints 1-3 [rad] (S, 3): the paths' samples one path after another.
            starts: index of each path's first sample, increasing from 0, shape (P,).
            q_prev: wrist angles (P, 3) just before each path.
            frames: ``BatchFK.frames`` of ``q123`` through ``link_3`` when the caller has them.

        Returns:
            Wrist angles [rad] (S, 3).
        """
        q123 = np.atleast_2d(q123)
        starts = np.asarray(starts, dtype=np.intp)
        q_prev = np.asarray(q_prev, dtype=np.float64).reshape(-1, 3)
        counts = np.diff(np.append(starts, len(q123)))
        if frames is None:
            q = np.zeros((len(q123), 6))
            q[:, :3] = q123
            frames = self.fk.frames(q, until="link_3")
        rot, pos = frames
        # the rotation inside a (S, 4, 4) pose, as solve() reads it: einsum sums in an order
        # that depends on the strides
        R03 = assemble({"link_3": rot["link_3"]}, pos)["link_3"][:, :3, :3]
        v = np.einsum("nji,j->ni", R03, self.normal)
        q5 = fo.arccos(np.clip(v[:, 0], -1.0, 1.0))
        theta = fo.arctan2(v[:, 1], -v[:, 2])
        inner = np.ones(len(q123), dtype=bool)  # sample k > 0 of its path
        inner[starts] = False
        dtheta = np.diff(theta)
        jump = np.abs(_wrapped(dtheta)) > 0.5 * np.pi
        jump &= inner[1:]
        flips = np.cumsum(np.r_[0, jump])
        flips -= np.repeat(flips[starts], counts)
        sign = np.where(flips % 2 == 0, 1.0, -1.0)
        q4 = theta + np.where(sign < 0, np.pi, 0.0)
        q5 = sign * q5
        f4, f5, p4, p5 = q4[starts], q5[starts], q_prev[:, 0], q_prev[:, 1]
        flip = _angs(f4 + np.pi - p4) + np.abs(-f5 - p5) < _angs(f4 - p4) + np.abs(f5 - p5)
        flip = np.repeat(flip, counts)
        q4 = np.where(flip, q4 + np.pi, q4)
        q5 = np.where(flip, -q5, q5)
        wraps = inner[1:] & (np.abs(np.diff(q4)) >= np.pi)
        unwrapped = q4.copy()
        unwrapped[1:] = q4[1:] + 0.0  # np.unwrap adds its (here zero) corrections
        for p in np.unique(np.searchsorted(starts, np.flatnonzero(wraps) + 1, side="right") - 1):
            s = slice(starts[p], starts[p] + counts[p])
            unwrapped[s] = np.unwrap(q4[s])
        turns = np.round((p4 - unwrapped[starts]) / (2 * np.pi))
        unwrapped += np.repeat(2 * np.pi * turns, counts)
        return np.column_stack([unwrapped, q5, np.repeat(q_prev[:, 2], counts)])

    def solve_one(self, q123, q_prev, normal=None) -> np.ndarray:
        """Wrist angles [rad] (3,) for one configuration of joints 1-3 [rad] (3,).

        Bit for bit ``solve(q123[None], q_prev, normal)[0]``, on Python floats: much cheaper
        than the batch path for one configuration, for the 4 ms control loop
        (docs/BENCHMARKS.md, "Kernel figures the code refers to"). (Arms whose
        joints 1-3 are not frame-axis rotations without origin rotations take the batch path.)

        Args:
            q123: joints 1-3, shape (3,).
            q_prev: wrist angles (3,) just before (the branch and 2 pi wrap nearest them).
            normal: shield normal in ``base`` (unit (3,)); default: the constructor's.
        """
        n = self.normal if normal is None else normal
        if self._arm is None:
            return self.solve(np.asarray(q123, dtype=np.float64)[None], q_prev, n)[0]
        R = _rotation_03(self._arm, q123)
        nx, ny, nz = (float(c) for c in n[:3])
        v0 = R[0][0] * nx + R[1][0] * ny + R[2][0] * nz  # R03^T n, summed as einsum does
        v1 = R[0][1] * nx + R[1][1] * ny + R[2][1] * nz
        v2 = R[0][2] * nx + R[1][2] * ny + R[2][2] * nz
        # the C library's acos and atan2, as solve() (fixed_order) takes them
        q5 = math.acos(min(max(v0, -1.0), 1.0))
        q4 = math.atan2(v1, -v2)
        p4, p5 = float(q_prev[0]), float(q_prev[1])
        if _ang(q4 + np.pi - p4) + abs(-q5 - p5) < _ang(q4 - p4) + abs(q5 - p5):
            q4, q5 = q4 + np.pi, -q5
        q4 += 2 * np.pi * round((p4 - q4) / (2 * np.pi))
        return np.array([q4, q5, float(q_prev[2])])


def _wrapped(d: np.ndarray) -> np.ndarray:
    """Angles ``d`` [rad] wrapped into [-pi, pi], as ``np.angle(np.exp(1j * d))`` (the angle by
    the C library's atan2: :mod:`fixed_order`)."""
    e = np.exp(1j * d)
    return fo.arctan2(e.imag, e.real)


def _arm_rotations(robot: Robot) -> tuple | None:
    """Joints up to ``link_3`` as the root's rotation (3 rows: a placed robot's
    ``plane_placement``, else the identity) and ``(index, i, j, sign)`` column mixes (see
    BatchFK), or None when another joint has an origin rotation or an axis off the frame axes."""
    steps = []
    start = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    for n, jt in enumerate(robot.chain):
        turned = not np.allclose(jt.T_parent_joint[:3, :3], np.eye(3))
        if turned and n == 0 and jt.index < 0 and not jt.axis.any():
            start = [[float(v) for v in row] for row in jt.T_parent_joint[:3, :3]]
            continue
        if turned:
            return None
        if jt.index >= 0:
            k = int(np.argmax(np.abs(jt.axis)))
            if abs(abs(jt.axis[k]) - 1.0) >= 1e-12:
                return None
            steps.append((jt.index, (k + 1) % 3, (k + 2) % 3, float(np.sign(jt.axis[k]))))
        if jt.child == "link_3":
            return start, tuple(steps)
    return None


def _rotation_03(arm: tuple, q) -> list[list[float]]:
    """Rotation of ``link_3`` in the robot's root frame (3 rows of 3 floats) for joints ``q``
    [rad].

    The same float operations as ``BatchFK.link_poses`` (columns i, j mixed by cos and sin).
    """
    start, steps = arm
    R = [list(row) for row in start]
    for index, i, j, sign in steps:
        angle = float(q[index])
        c, s = math.cos(angle), sign * math.sin(angle)
        for row in R:
            ri, rj = row[i], row[j]
            row[i], row[j] = c * ri + s * rj, -s * ri + c * rj
    return R


def _ang(a: float) -> float:
    """Absolute angle difference wrapped to [0, pi]."""
    return abs((a + np.pi) % (2 * np.pi) - np.pi)


def _angs(a: np.ndarray) -> np.ndarray:
    """:func:`_ang` element-wise."""
    return np.abs((a + np.pi) % (2 * np.pi) - np.pi)
