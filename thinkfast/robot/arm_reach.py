"""Where joints 1-3 put the shield when the wrist holds it coplanar: the wrist centre's forward
kinematics, in closed form, for the optimisation-based planners (``mpc``, ``jpl``).

The wrist is spherical (joints 4-6 about axes through one point, :mod:`thinkfast.robot.wrist`),
so the wrist centre (joint_5's origin) depends on joints 1-3 alone, and a shield centred on
link_6's axis at distance ``reach`` from it sits at ``wc(q123) + reach * n`` whenever the wrist
holds its normal along ``n``. The shield at a point ``p`` of the plane with the plane's normal
``n`` is then the three equations ``wc(q123) = p - reach * n``: the terminal constraint of an
interception, with no wrist angle among the unknowns.

:class:`WristCentre` evaluates ``wc`` and its Jacobian with numpy, and builds the same
expression for CasADi (imported only then), from the robot's URDF chain (the mount of a placed
robot included): one model, checked against Pinocchio's (tests/test_arm_reach.py).
"""

from __future__ import annotations

import math

import numpy as np

from thinkfast.errors import RobotModelError
from thinkfast.robot.model import Robot

WRIST_JOINT = "joint_5"  # its origin is the wrist centre (on joint_4's and joint_6's axes)


def _axis_rotation(ops, axis, q):
    """Rotation (3, 3) by ``q`` about the unit ``axis`` (Rodrigues), with ``ops`` numpy-like."""
    x, y, z = (float(a) for a in axis)
    c, s = ops.cos(q), ops.sin(q)
    t = 1 - c
    rows = [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
    return ops.matrix(rows)


class _Numpy:
    cos, sin = staticmethod(math.cos), staticmethod(math.sin)

    @staticmethod
    def matrix(rows):
        return np.array(rows, dtype=float)

    @staticmethod
    def matmul(a, b):
        return a @ b


class _Casadi:
    def __init__(self):
        import casadi as ca

        self.ca = ca
        self.cos, self.sin = ca.cos, ca.sin

    def matrix(self, rows):
        return self.ca.vertcat(*(self.ca.horzcat(*r) for r in rows))

    def matmul(self, a, b):
        return self.ca.mtimes(a, b)


class WristCentre:
    """The wrist centre as a function of joints 1-3 (module doc).

    Args:
        robot: the robot (placed or not: the result is in its frame).

    Raises:
        RobotModelError: no ``joint_5``, or a joint among the wrist centre's ancestors other than
            joints 1-3 moves it.
    """

    def __init__(self, robot: Robot):
        self.n = robot.n_arm
        by_child = {j.child: j for j in robot.chain}
        wrist = next((j for j in robot.chain if j.name == WRIST_JOINT), None)
        if wrist is None:
            raise RobotModelError(f"no {WRIST_JOINT}: the wrist centre is its origin")
        path = []  # joints from the root to joint_5's parent link, root first
        link = wrist.parent
        while link in by_child:
            j = by_child[link]
            path.append(j)
            link = j.parent
        path.reverse()
        self._path = path
        self._last = wrist.T_parent_joint
        self._wrist_link = wrist.child  # its frame's origin is joint_5's
        self._check(robot)

    def _chain(self, ops, q):
        """(R, p) of joint_5's origin for joints 1-3 ``q`` (q4 and later at zero: they do not
        move it, checked at construction)."""
        R, p = (
            ops.matrix([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]),
            ops.matrix([[0.0], [0.0], [0.0]]),
        )
        for j in self._path + [None]:
            T = self._last if j is None else j.T_parent_joint
            p = p + ops.matmul(
                R, ops.matrix([[float(T[0, 3])], [float(T[1, 3])], [float(T[2, 3])]])
            )
            R = ops.matmul(R, ops.matrix(T[:3, :3].tolist()))
            if j is not None and 0 <= j.index < self.n:  # joint_4 at zero: it does not move
                R = ops.matmul(R, _axis_rotation(ops, j.axis, q[j.index]))  # the centre
        return R, p

    def position(self, q123) -> np.ndarray:
        """The wrist centre (3,) [m] at joints 1-3 ``q123`` [rad]."""
        out = self._chain(_Numpy, [float(x) for x in q123[: self.n]])
        return np.asarray(out[1], dtype=float).reshape(3)

    def jacobian(self, q123, h: float = 1e-7) -> np.ndarray:
        """d wc / d q123 (3, n), by central differences of the closed form."""
        q = np.asarray(q123[: self.n], dtype=float)
        J = np.empty((3, self.n))
        for i in range(self.n):
            dq = np.zeros(self.n)
            dq[i] = h
            J[:, i] = (self.position(q + dq) - self.position(q - dq)) / (2 * h)
        return J

    def casadi(self, q):
        """The wrist centre as a CasADi column (3, 1) of the symbol ``q`` (n,)."""
        return self._chain(_Casadi(), [q[i] for i in range(self.n)])[1]

    def _check(self, robot: Robot) -> None:
        from thinkfast.robot.kinematics import Kinematics

        kin = Kinematics(robot)
        rng = np.random.default_rng(0)  # a fixed check, not a sample: the same every time
        q = np.array(robot.any_q, dtype=float)
        for _ in range(4):
            q_try = np.clip(q + rng.uniform(-0.5, 0.5, q.size), robot.q_lower, robot.q_upper)
            got = self.position(q_try)
            want = kin.fk(q_try, self._wrist_link)[:3, 3]
            if np.linalg.norm(got - want) > 1e-9:
                raise RobotModelError(
                    f"{WRIST_JOINT}'s origin moves with the wrist joints: not a spherical wrist"
                )
        wc = self.position(q)
        pose = kin.shield(q)
        d = pose.centre - wc
        self.reach = float(np.dot(d, pose.normal))  # shield centre ahead of the wrist centre
        off = d - self.reach * pose.normal
        if np.linalg.norm(off) > 1e-6:
            raise RobotModelError(
                f"the shield centre is {1e3 * np.linalg.norm(off):.2f} mm off link_6's axis: "
                "the wrist-centre reach model needs it on the axis"
            )

    def target(self, point, normal) -> np.ndarray:
        """The wrist centre (3,) that puts the shield centre at ``point`` with normal ``normal``."""
        n = np.asarray(normal, dtype=float)
        return np.asarray(point, dtype=float) - self.reach * n / np.linalg.norm(n)
