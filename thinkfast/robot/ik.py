"""Numerical inverse kinematics of the shield disk (Pinocchio Jacobians, Levenberg-Marquardt).

Task: shield centre at a point [m] and shield normal along a unit vector, both in ``base``. The
disk is symmetric about its normal and joint_6 turns about that normal through the disk centre, so
joint_6 is held at the seed's value and joints 1-5 solve the 5-dimensional task.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.robot import fixed_order as fo
from thinkfast.robot.kinematics import Kinematics


class IkResult(NamedTuple):
    """Outcome of :func:`solve_shield_ik`.

    Attributes:
        q: joint angles [rad] (6,) at the last iterate.
        position_error: shield centre residual [m].
        normal_error: angle between shield normal and target normal [rad].
        iterations: iterations used.
        converged: residuals below tolerance.
    """

    q: np.ndarray
    position_error: float
    normal_error: float
    iterations: int
    converged: bool


def solve_shield_ik(
    kin: Kinematics,
    centre: np.ndarray,
    normal: np.ndarray,
    q_seed: np.ndarray,
    *,
    tol: float = 1e-9,
    max_iter: int = 60,
) -> IkResult:
    """Joint angles putting the shield centre at ``centre`` with normal ``normal``.

    Args:
        kin: kinematics of the robot.
        centre: target shield centre in ``base`` [m], shape (3,).
        normal: target shield normal in ``base`` (normalised here), shape (3,).
        q_seed: start configuration [rad], shape (6,); joint_6 stays at its value.
        tol: convergence tolerance on the position residual [m] and the normal residual [-].
        max_iter: iteration cap.

    Returns:
        The final iterate; check ``converged`` (the iterate is returned either way so callers can
        report how close it came). Joint limits are not enforced here.
    """
    centre = np.asarray(centre, dtype=np.float64)
    n_target = np.asarray(normal, dtype=np.float64)
    n_target = n_target / fo.norm(n_target)
    q = np.array(q_seed, dtype=np.float64)
    lam, iterations = 1e-3, 0

    def residual(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pose, Jp, Jn = kin.shield_jacobian(q)
        r = np.concatenate([pose.centre - centre, pose.normal - n_target])
        return r, np.concatenate((Jp, Jn))[:, :5]  # np.vstack, unwrapped

    r, J = residual(q)
    diag = (np.arange(5), np.arange(5))
    while iterations < max_iter:
        if fo.norm(r[:3]) < tol and fo.norm(r[3:]) < tol:
            break
        iterations += 1
        H = fo.matmul(J.T, J)
        damp = np.zeros_like(H)
        damp[diag] = H[diag] + 1e-9  # np.diag(np.diag(H) + 1e-9)
        dq = fo.solve(H + lam * damp, -fo.matvec(J.T, r))
        trial = q.copy()
        trial[:5] += dq
        r_new, J_new = residual(trial)
        if fo.dot(r_new, r_new) < fo.dot(r, r):  # accept, trust the model more
            q, r, J, lam = trial, r_new, J_new, max(lam * 0.3, 1e-9)
        else:  # reject, damp harder
            lam *= 10.0
            if lam > 1e6:
                break
    pose = kin.shield(q)
    pos_err = float(fo.norm(pose.centre - centre))
    ang_err = float(
        math.atan2(fo.norm(np.cross(pose.normal, n_target)), fo.dot(pose.normal, n_target))
    )
    return IkResult(q, pos_err, ang_err, iterations, bool(pos_err < 1e-6 and ang_err < 1e-6))
