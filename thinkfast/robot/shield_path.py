"""Shield centres along joint 1-3 motions, with the wrist keeping the shield normal fixed.

On the x-y-x wrist (:mod:`thinkfast.robot.wrist`) the shield normal is link_5's x axis, and the
shield centre lies on that axis at a fixed distance ``L`` from the wrist centre (the origin of
link_5, which joint_4 does not move: joint_5 sits on joint_4's axis). So whatever wrist angles
the rule picks for a normal n (branch, 2 pi wraps, joint_6),

    shield centre = wrist centre(q1, q2, q3) + L n,

and the batched FK only has to pose the arm up to link_5 (the tests hold this to the full FK
with the coplanar rule's wrist angles at 1e-12). The constructor checks both conditions on the
robot and refuses a robot where they fail.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from thinkfast.errors import RobotModelError
from thinkfast.robot import fixed_order as fo
from thinkfast.robot import kernels
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.model import Robot
from thinkfast.robot.wrist import check_wrist_geometry


class ShieldSampler:
    """Shield centres [m] in ``base`` for joints 1-3 under a fixed shield normal.

    Args:
        robot: the robot (x-y-x wrist, shield centre on link_5's x axis).

    Raises:
        RobotModelError: the wrist or the shield mounting differs from that.
    """

    def __init__(self, robot: Robot):
        check_wrist_geometry(robot)
        by_name = {j.name: j for j in robot.chain}
        j5 = by_name["joint_5"]
        if not np.allclose(j5.T_parent_joint[1:3, 3], 0.0, atol=1e-12):
            raise RobotModelError("shield path: joint_5 must sit on joint_4's x axis")
        self.robot = robot
        self.fk = BatchFK(robot)
        self.wrist_link = j5.child
        q = np.array(robot.any_q, dtype=float)[None]
        poses = self.fk.link_poses(q, until=robot.shield_link)
        w, s = poses[self.wrist_link][0], poses[robot.shield_link][0]
        local = fo.matvec(w[:3, :3].T, s[:3, 3] - w[:3, 3])  # in link_5: along x only
        if not (np.allclose(local[1:], 0.0, atol=1e-9) and np.allclose(w[:3, 0], s[:3, 2])):
            raise RobotModelError(
                "shield path: the shield centre must lie on link_5's x axis, normal along it"
            )
        self.offset = float(local[0])  # L [m]
        self._mount: tuple | None = None  # (R0, t0) of a turned root, after the chain
        self._wrist_point, self._chain = self._wrist_chain()
        self._plan = self._row_plan()
        self._offsets: dict[tuple, np.ndarray] = {}

    def _wrist_chain(self) -> tuple[np.ndarray, list]:
        """The joints from ``base`` to the wrist centre, last first, as the point they move
        (the wrist centre after the steps that do not depend on joints 1-3, which are fixed
        transforms for joints 4 and 5: they turn about axes through it) and the remaining steps
        (R0, t0, rotation, index): a rotation about a frame axis is (k, i, j, sign), else the
        unit axis (Rodrigues); R0 None where it is the identity, t0 None where it is zero."""
        steps, link = [], self.wrist_link
        by_child = {j.child: j for j in self.robot.chain}
        while link in by_child:
            j = by_child[link]
            index = j.index if 0 <= j.index < 3 else -1
            R0, t0 = j.T_parent_joint[:3, :3].copy(), j.T_parent_joint[:3, 3].copy()
            axis = np.asarray(j.axis, dtype=float)
            k = int(np.argmax(np.abs(axis)))
            rot = axis
            if abs(abs(axis[k]) - 1.0) < 1e-12:  # about a frame axis: mix two components
                rot = (k, (k + 1) % 3, (k + 2) % 3, float(np.sign(axis[k])))
            if index < 0 and not axis.any():
                rot = (0, 1, 2, 1.0)  # a fixed joint turns nothing: any frame axis will do
            steps.append((None if np.array_equal(R0, np.eye(3)) else R0,
                          None if not t0.any() else t0, rot, index))  # fmt: skip
            link = j.parent
        if steps and steps[-1][0] is not None and steps[-1][3] < 0:
            # the root's own turn (a placed robot's plane_placement): applied after the rows
            self._mount = steps.pop()[:2]
        p = np.zeros((1, 3))
        while steps and steps[0][3] < 0:  # the same arithmetic on one point
            R0, t0, _, _ = steps.pop(0)
            p = _place(p, R0, t0)
        return p[0], steps

    def wrist_centres(self, q123: np.ndarray) -> np.ndarray:
        """Wrist centres [m] (N, 3) in ``base`` for joints 1-3 (N, 3) [rad]: the chain applied
        to a point from the wrist back to ``base`` (the tests hold it to the batched FK)."""
        q123 = np.asarray(q123, dtype=float)
        p = np.broadcast_to(self._wrist_point, (len(q123), 3))
        for R0, t0, rot, index in self._chain:
            if index >= 0:  # p <- Rot(axis, q) p
                a = q123[:, index]
                if isinstance(rot, tuple):
                    k, i, j, sign = rot
                    c, s = np.cos(a), np.sin(a)
                    if sign < 0.0:
                        s = -s
                    out = np.empty((len(q123), 3))
                    pi, pj = p[:, i], p[:, j]
                    np.subtract(c * pi, s * pj, out=out[:, i])
                    np.add(s * pi, c * pj, out=out[:, j])
                    out[:, k] = p[:, k]
                    p = out
                else:  # Rodrigues
                    axis = rot
                    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
                    cross = np.column_stack([axis[1] * p[:, 2] - axis[2] * p[:, 1],
                                             axis[2] * p[:, 0] - axis[0] * p[:, 2],
                                             axis[0] * p[:, 1] - axis[1] * p[:, 0]])  # fmt: skip
                    p = c * p + s * cross + (1.0 - c) * fo.dot(p, axis)[:, None] * axis
            p = _place(p, R0, t0)
        if self._mount is not None:
            p = _place(p, *self._mount)
        return np.array(p)

    def centres(self, q123: np.ndarray, normal=(1.0, 0.0, 0.0)) -> np.ndarray:
        """Shield centres [m], shape (..., 3), for joints 1-3 [rad], shape (..., 3).

        Args:
            q123: joint 1-3 angles, any leading shape (e.g. (M, T, 3)).
            normal: shield normal in ``base`` (unit (3,)); +x is the coplanar rule.
        """
        q123 = np.asarray(q123, dtype=float)
        wc = self.wrist_centres(q123.reshape(-1, 3))
        wc += self._offset(normal)
        return wc.reshape(q123.shape)

    def centre_rows(self, q123: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """:meth:`centres` (normal +x) of joints 1-3 (N, 3) [rad] as rows x, y, z [m], shape
        (3, N), into ``out`` when given: the same values bit for bit, computed row by row (the
        same operations on contiguous rows, without the (N, 3) layout's strided columns), in
        one compiled pass (:mod:`shield_jit`) when the kernels are compiled (:mod:`kernels`)."""
        q123 = np.asarray(q123, dtype=float)
        out = np.empty((3, len(q123))) if out is None else out
        off = self._offset((1.0, 0.0, 0.0))
        if (
            self._plan is not None
            and out.flags.c_contiguous
            and out.dtype == np.float64
            and kernels.compiled()
        ):
            from thinkfast.robot.shield_jit import chain_rows

            joints, (point, rot_i, rot_j, rot_q, neg, has_t0, t0) = self._plan
            trig = np.empty((2, 3, len(q123)))
            for k in joints:  # numpy's cos and sin of the same columns, as the numpy rows
                np.cos(q123[:, k], out=trig[0, k])
                np.sin(q123[:, k], out=trig[1, k])
            if self._mount is None:
                chain_rows(point, rot_i, rot_j, rot_q, neg, has_t0, t0, trig, off, out)
                return out
            chain_rows(point, rot_i, rot_j, rot_q, neg, has_t0, t0, trig, np.zeros(3), out)
            rows = self._mounted(list(out))
        else:
            rows = self._mounted(self._wrist_rows(q123))
        for c in range(3):
            np.add(rows[c], off[c], out=out[c])
        return out

    def _mounted(self, rows: list) -> list:
        """Rows x, y, z of wrist centres in the robot's root frame, turned by the mount (a
        placed robot's ``plane_placement``; as given when there is none)."""
        if self._mount is None:
            return rows
        R0, t0 = self._mount
        out = []
        for i in range(3):
            r = R0[i, 0] * rows[0] + R0[i, 1] * rows[1] + R0[i, 2] * rows[2]  # _place's order
            out.append(r if t0 is None else r + t0[i])
        return out

    def _row_plan(self) -> tuple | None:
        """The chain as arrays for the compiled row pass, or None when a step is not a
        rotation about a frame axis without a fixed rotation (then the numpy rows)."""
        if any(R0 is not None or not isinstance(rot, tuple) for R0, _, rot, _ in self._chain):
            return None
        steps = self._chain
        return sorted({index for *_, index in steps if index >= 0}), (
            np.array(self._wrist_point, dtype=float),
            np.array([rot[1] for _, _, rot, _ in steps], dtype=np.intp),
            np.array([rot[2] for _, _, rot, _ in steps], dtype=np.intp),
            np.array([index for _, _, _, index in steps], dtype=np.intp),
            np.array([rot[3] < 0.0 for _, _, rot, _ in steps], dtype=np.bool_),
            np.array([t0 is not None for _, t0, _, _ in steps], dtype=np.bool_),
            np.array(
                [np.zeros(3) if t0 is None else t0 for _, t0, _, _ in steps], dtype=float
            ).reshape(-1, 3),
        )

    def _wrist_rows(self, q123: np.ndarray) -> list:
        """:meth:`wrist_centres` as three rows (N,) (a row the chain never changes may stay a
        scalar): every step's arithmetic as there, element by element."""
        if any(R0 is not None or not isinstance(rot, tuple) for R0, _, rot, _ in self._chain):
            return list(self.wrist_centres(q123).T)  # a general chain: the (N, 3) code
        p = [float(x) for x in self._wrist_point]  # as its broadcast rows
        for _, t0, (_k, i, j, sign), index in self._chain:
            if index >= 0:
                a = q123[:, index]
                c, s = np.cos(a), np.sin(a)
                if sign < 0.0:
                    s = -s
                pi, pj = p[i], p[j]
                p[i] = c * pi - s * pj
                p[j] = s * pi + c * pj
            if t0 is not None:
                p = [p[0] + t0[0], p[1] + t0[1], p[2] + t0[2]]
        return p

    def _offset(self, normal) -> np.ndarray:
        """The shield centre's offset from the wrist centre [m] (3,) for a shield ``normal``."""
        key = tuple(map(float, normal))
        if key not in self._offsets:
            n = np.asarray(key)
            self._offsets[key] = self.offset * (n / fo.norm(n))
        return self._offsets[key]


def _place(p: np.ndarray, R0: np.ndarray | None, t0: np.ndarray | None) -> np.ndarray:
    """``p @ R0.T + t0`` (N, 3), skipping an identity ``R0`` or a zero ``t0`` (None)."""
    if R0 is not None:
        p = fo.matmul(p, R0.T)
    return p if t0 is None else p + t0


def sample_joint_paths(trajectories: Sequence, times: np.ndarray) -> np.ndarray:
    """Joint 1-3 positions [rad], shape (M, T, 3), of Ruckig trajectories at ``times`` [s] (T,).

    Each trajectory is read at ``clip(t, 0, duration)``: at its start before 0 and held at its
    end afterwards (every motion here ends at rest).
    """
    times = np.asarray(times, dtype=float)
    out = np.empty((len(trajectories), len(times), 3))
    for m, traj in enumerate(trajectories):
        dur = traj.duration
        for i, t in enumerate(np.clip(times, 0.0, dur).tolist()):
            out[m, i] = traj.at_time(t)[0]
    return out
