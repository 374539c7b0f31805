"""Camera-to-base fit: the pose of ``camera`` in ``base`` from a ball on the shield at known poses.

At pose ``i`` the ball centre is ``b_i = c_s(q_i) + R_s(q_i) o`` in ``base`` (shield centre
``c_s``, shield rotation ``R_s``, ``o`` the ball's offset in the shield frame: along the normal,
half the shield's thickness plus the ball radius). The camera measures ``m = R^T (b - c)`` plus
stereo noise; the fit finds ``(R, c)`` (and optionally ``o``) by nonlinear least squares over
every detection, each residual whitened by the camera model's depth-dependent covariance
(depth noise ``d^2 sigma_disp / (f B)`` along the ray, ``d sigma_px / f`` across), with a robust
loss first and a plain one on the inliers after. The start is the closed-form (Kabsch) fit of
the per-pose medians, so no initial guess is needed.
"""

from __future__ import annotations

import json
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from thinkfast.calib.camera_record import CalibPose
from thinkfast.decide.tree_view import BALL_RADIUS
from thinkfast.errors import ThinkfastError
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import Robot
from thinkfast.sim.camera import CameraModelConfig, noise_covariance

GATE = 4.03  # whitened residual norm at the 99.9 % quantile of chi with 3 degrees of freedom
DISPARITY_SIGMA = 0.25  # px, weighting only: the upper end of CameraModelConfig's range
MIN_POSE_DETECTIONS = 3
OUTLIER_POSE_FLOOR = 0.005  # m: a pose is flagged only when its residual is above this too


class PoseResidual(NamedTuple):
    """Fit residual at one pose.

    Attributes:
        index: pose index in the record (0-based).
        detections: detections of the pose.
        inliers: detections inside the gate.
        error: mean inlier measurement minus prediction in ``camera`` [m] (3,); NaN if none.
        depth: predicted depth of the ball [m].
        flag: "" (fine), "few" (fewer than 3 detections: not fitted), "outlier" (residual
            more than 3x the median pose's and above 5 mm, or fewer than 3 detections left
            inside the gate: error is then the mean of all its detections).
    """

    index: int
    detections: int
    inliers: int
    error: np.ndarray
    depth: float
    flag: str


class CameraFit(NamedTuple):
    """Result of :func:`fit_camera`.

    Attributes:
        xyz: camera origin in ``base`` [m] (3,).
        rpy: camera orientation (roll, pitch, yaw, ``R = Rz Ry Rx``) [rad] (3,).
        R: ``R_base_camera`` (3, 3).
        ball_offset: ball centre in the shield frame [m] (3,) (fitted or as given).
        poses: residual per pose, in record order.
        rms: RMS of the inlier detections' residual norms [m].
        detections, outliers: detections used and gated out.
        std_xyz: standard deviation of ``xyz`` [m] (3,) (frames taken as independent).
        std_angle: standard deviation of the orientation about base x, y, z [rad] (3,).
        scale: robust scale of the whitened residuals (1: the noise model fits).
    """

    xyz: np.ndarray
    rpy: np.ndarray
    R: np.ndarray
    ball_offset: np.ndarray
    poses: list[PoseResidual]
    rms: float
    detections: int
    outliers: int
    std_xyz: np.ndarray
    std_angle: np.ndarray
    scale: float


def default_ball_offset(robot: Robot, ball_radius: float = BALL_RADIUS) -> np.ndarray:
    """Ball centre on the shield's face centre, in the shield frame [m] (3,)."""
    return np.array([0.0, 0.0, robot.shield_thickness / 2.0 + ball_radius])


def shield_frames(kin: Kinematics, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shield centres [m] (P, 3) and rotations (P, 3, 3) in ``base`` at joint angles (P, 6)."""
    T = np.array([kin.fk(q, kin.robot.shield_link) for q in np.atleast_2d(qs)])
    return T[:, :3, 3].copy(), T[:, :3, :3].copy()


def ball_positions(kin: Kinematics, qs: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Ball centres in ``base`` [m] (P, 3) at joint angles ``qs`` (P, 6)."""
    c, R = shield_frames(kin, qs)
    return c + R @ np.asarray(offset, dtype=float)


def kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) with ``b ~ R a + t`` (least squares, points (P, 3))."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cb - R @ ca


def rpy_from_rotation(R: np.ndarray) -> np.ndarray:
    """Fixed-axis roll, pitch, yaw [rad] (3,) of ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    return Rotation.from_matrix(R).as_euler("xyz")


def fit_camera(
    poses: list[CalibPose],
    robot: Robot,
    *,
    ball_offset: np.ndarray | None = None,
    fit_offset: bool = False,
    camera: CameraModelConfig = CameraModelConfig(),
) -> CameraFit:
    """Fit the camera pose in ``base`` to a calibration record's poses.

    Args:
        poses: the record's poses (joint angles and detections in ``camera``).
        robot: the arm (forward kinematics, shield size).
        ball_offset: ball centre in the shield frame [m] (3,); default: the face centre.
        fit_offset: fit the ball offset too (needs varied shield orientations).
        camera: camera model (focal length, baseline, pixel noise) for the weights.

    Raises:
        ThinkfastError: fewer than 3 poses (4 with ``fit_offset``) with enough detections, or
            their ball positions are (nearly) collinear.
    """
    kin = Kinematics(robot)
    offset0 = default_ball_offset(robot) if ball_offset is None else np.asarray(ball_offset)
    counts = np.array([len(p.positions) for p in poses])
    usable = np.flatnonzero(counts >= MIN_POSE_DETECTIONS)
    need = 4 if fit_offset else 3
    if len(usable) < need:
        raise ThinkfastError(
            f"only {len(usable)} poses with >= {MIN_POSE_DETECTIONS} detections; the fit needs "
            f"at least {need} (12 recommended)"
        )
    qs = np.array([poses[i].q for i in usable])
    centres, rots = shield_frames(kin, qs)
    meas = np.concatenate([poses[i].positions for i in usable])
    owner = np.repeat(np.arange(len(usable)), counts[usable])
    medians = np.array([np.median(poses[i].positions, axis=0) for i in usable])
    b0 = centres + rots @ offset0
    spread = np.linalg.svd(b0 - b0.mean(axis=0), compute_uv=False)
    if spread[1] < 0.05:
        raise ThinkfastError(
            f"ball positions of the poses are nearly collinear (spread {spread.round(3)} m): "
            "the rotation about their line is not determined; use well-spread poses "
            "(thinkfast-calib poses)"
        )
    R0, c0 = kabsch(medians, b0)
    cov = noise_covariance(meas, DISPARITY_SIGMA, camera)
    Linv = np.linalg.inv(np.linalg.cholesky(cov))  # whitening (N, 3, 3)

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        R = R0 @ Rotation.from_rotvec(x[3:6]).as_matrix()
        return R, c0 + x[:3], (offset0 + x[6:9]) if fit_offset else offset0

    def residual(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
        R, c, o = unpack(x)
        pred = (centres + rots @ o - c) @ R  # rows R^T (b - c)
        e = meas[keep] - pred[owner[keep]]
        return np.einsum("nij,nj->ni", Linv[keep], e).ravel()

    x0 = np.zeros(9 if fit_offset else 6)
    every = np.ones(len(meas), dtype=bool)
    robust = least_squares(residual, x0, args=(every,), loss="soft_l1", f_scale=3.0)
    white = residual(robust.x, every).reshape(-1, 3)
    scale = max(1.0, 1.4826 * float(np.median(np.abs(white))))
    inlier = np.linalg.norm(white, axis=1) <= GATE * scale
    final = least_squares(residual, robust.x, args=(inlier,))
    R, c, o = unpack(final.x)
    pred = (centres + rots @ o - c) @ R
    err = meas - pred[owner]
    white = residual(final.x, every).reshape(-1, 3)
    inlier = np.linalg.norm(white, axis=1) <= GATE * scale
    dof = max(1, 3 * int(inlier.sum()) - len(final.x))
    s2 = float(final.fun @ final.fun) / dof
    try:
        pcov = np.linalg.inv(final.jac.T @ final.jac) * s2
    except np.linalg.LinAlgError:
        pcov = np.full((len(final.x),) * 2, np.inf)
    std = np.sqrt(np.abs(np.diag(pcov)))
    rows = _pose_rows(poses, usable, owner, err, inlier, pred)
    return CameraFit(
        xyz=c,
        rpy=rpy_from_rotation(R),
        R=R,
        ball_offset=np.asarray(o, dtype=float),
        poses=rows,
        rms=float(np.sqrt(np.mean(np.sum(err[inlier] ** 2, axis=1)))),
        detections=int(inlier.sum()),
        outliers=int((~inlier).sum()),
        std_xyz=std[:3],
        std_angle=std[3:6],  # rotvec of R0^T R: about the camera axes, same size as about base
        scale=scale,
    )


def _pose_rows(poses, usable, owner, err, inlier, pred) -> list[PoseResidual]:
    """Per-pose residuals and flags, in record order."""
    rows: list[PoseResidual] = []
    by_pose = {int(i): k for k, i in enumerate(usable)}
    for i, p in enumerate(poses):
        k = by_pose.get(i)
        if k is None:
            rows.append(PoseResidual(i, len(p.positions), 0, np.full(3, np.nan), np.nan, "few"))
            continue
        sel = (owner == k) & inlier
        if sel.sum() >= MIN_POSE_DETECTIONS:
            e, flag = err[sel].mean(axis=0), ""
        else:  # its detections disagree with the fit: a wrong pose, or the ball moved
            e, flag = err[owner == k].mean(axis=0), "outlier"
        rows.append(PoseResidual(i, len(p.positions), int(sel.sum()), e, float(pred[k, 0]), flag))
    norms = np.array([np.linalg.norm(r.error) for r in rows if not r.flag])
    if len(norms):
        limit = max(3.0 * float(np.median(norms)), OUTLIER_POSE_FLOOR)
        rows = [
            r._replace(flag="outlier") if not r.flag and np.linalg.norm(r.error) > limit else r
            for r in rows
        ]
    return rows


def fit_report(fit: CameraFit, source: str) -> str:
    """A person's summary of ``fit``: pose, uncertainty and the residual of every pose."""
    deg = np.degrees
    lines = [
        f"camera pose in base from {source}:",
        f"  xyz = [{', '.join(f'{v:.4f}' for v in fit.xyz)}] m  "
        f"(std {', '.join(f'{1e3 * v:.1f}' for v in fit.std_xyz)} mm)",
        f"  rpy = [{', '.join(f'{v:.5f}' for v in fit.rpy)}] rad = "
        f"[{', '.join(f'{v:.2f}' for v in deg(fit.rpy))}] deg  "
        f"(std {', '.join(f'{v:.2f}' for v in deg(fit.std_angle))} deg)",
        "  ball offset in the shield frame = "
        f"[{', '.join(f'{1e3 * v:.1f}' for v in fit.ball_offset)}] mm",
        f"  {fit.detections} detections used, {fit.outliers} gated out; rms residual "
        f"{1e3 * fit.rms:.1f} mm; noise scale {fit.scale:.2f} (1: as the camera model says)",
        "",
        "pose  dets  used  depth_m  err_x_mm  err_y_mm  err_z_mm  |err|_mm  flag",
    ]
    for r in fit.poses:
        e = 1e3 * r.error
        lines.append(
            f"{r.index:4d}  {r.detections:4d}  {r.inliers:4d}  {r.depth:7.3f}  {e[0]:8.2f}  "
            f"{e[1]:8.2f}  {e[2]:8.2f}  {np.linalg.norm(e):8.2f}  {r.flag}"
        )
    flagged = [r.index for r in fit.poses if r.flag]
    if flagged:
        lines.append(f"flagged poses: {', '.join(map(str, flagged))} (see docs/CALIBRATION.md)")
    return "\n".join(lines)


def camera_toml(fit: CameraFit, source: str, camera_id: str | None = None) -> str:
    """The fitted pose as a TOML file: a ``[camera]`` table that the run and detect configs take
    (``camera_file = "..."`` or pasted), and a ``[calibration]`` table they ignore. With
    ``camera_id`` (another camera than the default one, docs/CAMERAS.md) the pose is a
    ``[[cameras]]`` table with that ``id`` instead, to paste into the run config."""
    flagged = [r.index for r in fit.poses if r.flag]
    deg = np.degrees
    head = "[camera]\n" if camera_id is None else f"[[cameras]]\nid = {json.dumps(camera_id)}\n"
    return (
        f"# thinkfast-calib camera: pose of the camera in base, fitted from {source}\n"
        f"# rpy in degrees: [{', '.join(f'{v:.3f}' for v in deg(fit.rpy))}]\n"
        + head
        + f"xyz = [{', '.join(f'{v:.6f}' for v in fit.xyz)}]\n"
        f"rpy = [{', '.join(f'{v:.7f}' for v in fit.rpy)}]\n"
        "\n"
        "[calibration]\n"
        f"source = {json.dumps(source)}\n"
        f"poses = {len(fit.poses)}\n"
        f"flagged_poses = [{', '.join(map(str, flagged))}]\n"
        f"detections = {fit.detections}\n"
        f"outliers = {fit.outliers}\n"
        f"rms_residual = {fit.rms:.6f}  # m\n"
        f"std_xyz = [{', '.join(f'{v:.6f}' for v in fit.std_xyz)}]  # m\n"
        f"std_angle = [{', '.join(f'{v:.7f}' for v in fit.std_angle)}]  # rad\n"
        f"ball_offset = [{', '.join(f'{v:.6f}' for v in fit.ball_offset)}]  # m, shield frame\n"
    )
