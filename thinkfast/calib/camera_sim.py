"""Calibration poses and simulated calibration records (known camera pose, the ZED noise model).

:func:`pick_poses` samples joint configurations, keeps those whose shield-mounted ball the camera
sees face on (in the image with a margin, at a usable depth, the shield's face turned towards
the lens so the disk cannot hide the ball, within limits and collision free) and picks a
well-spread subset (greedy farthest point in the camera frame), ordered as a short tour from
home. :func:`simulate_camera_record` measures the ball at those poses with the camera model of
:mod:`thinkfast.sim.camera`: stereo depth noise along the ray, lateral pixel noise, gross
outliers and dropouts.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.calib.camera_fit import default_ball_offset
from thinkfast.calib.camera_record import CalibPose
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.errors import ThinkfastError
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import Robot
from thinkfast.sim.camera import (
    CameraModelConfig,
    dropout_mask,
    gross_error,
    in_view,
    measure,
)


class PoseSet(NamedTuple):
    """Chosen calibration poses: joint angles [rad] (P, 6), ball centres in ``camera`` [m]
    (P, 3), and the cosine between the shield normal and the direction to the lens (P,)."""

    q: np.ndarray
    ball_camera: np.ndarray
    facing: np.ndarray


def candidate_poses(
    robot: Robot,
    camera: CameraExtrinsic,
    rng: np.random.Generator,
    *,
    samples: int = 200_000,
    depth: tuple[float, float] = (0.4, 1.5),
    min_facing: float = 0.3,
    image_margin: float = 0.8,
    model: CameraModelConfig = CameraModelConfig(),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random configurations whose ball the camera sees well (before the collision check).

    Args:
        robot: the arm.
        camera: the camera pose in ``base`` (the assumed one before calibration).
        rng: randomness (joint samples).
        samples: configurations drawn uniformly within the joint limits (joint 1 within +-90
            deg: the arm faces forward; joint 6 within +-180 deg).
        depth: accepted ball depth range [m].
        min_facing: least cosine between the shield normal and the direction ball -> lens.
        image_margin: the ball must lie within this fraction of the half image size.
        model: camera model (focal length, image size).

    Returns:
        Joint angles (M, 6), ball centres in ``camera`` (M, 3), facing cosines (M,).
    """
    fk = BatchFK(robot)
    offset = default_ball_offset(robot)
    R, c = camera.rotation(), camera.translation()
    half = np.array(model.image_size, dtype=float) / 2.0 * image_margin
    out_q, out_p, out_f = [], [], []
    for start in range(0, samples, 50_000):
        n = min(50_000, samples - start)
        q = rng.uniform(robot.q_lower, robot.q_upper, (n, 6))
        q[:, 0] = rng.uniform(-np.pi / 2, np.pi / 2, n)  # the arm faces forward, towards the camera
        q[:, 5] = rng.uniform(-np.pi, np.pi, n)
        T = fk.link_poses(q, until=robot.shield_link)[robot.shield_link]
        normal = T[:, :3, 2]
        ball = T[:, :3, 3] + T[:, :3, :3] @ offset
        p_cam = (ball - c) @ R
        to_lens = c - ball
        facing = np.einsum("ij,ij->i", normal, to_lens) / np.linalg.norm(to_lens, axis=1)
        d = p_cam[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = model.focal_px * p_cam[:, 1:] / d[:, None]
        ok = (d >= depth[0]) & (d <= depth[1]) & (facing >= min_facing)
        ok &= (np.abs(uv) <= half).all(axis=1) & in_view(p_cam, model)
        out_q.append(q[ok])
        out_p.append(p_cam[ok])
        out_f.append(facing[ok])
    return np.concatenate(out_q), np.concatenate(out_p), np.concatenate(out_f)


def spread_subset(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` points (N, 3) picked greedily, each farthest from those picked."""
    first = int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))
    chosen = [first]
    dist = np.linalg.norm(points - points[first], axis=1)
    while len(chosen) < min(count, len(points)):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(points - points[nxt], axis=1))
    return np.array(chosen)


def tour_from(q_start: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """Order of ``qs`` (P, 6) as a nearest-neighbour tour in joint space from ``q_start``."""
    left, order, here = list(range(len(qs))), [], np.asarray(q_start)
    while left:
        k = min(left, key=lambda i: float(np.abs(qs[i] - here).max()))
        order.append(k)
        left.remove(k)
        here = qs[k]
    return np.array(order, dtype=int)


def pick_poses(
    robot: Robot,
    camera: CameraExtrinsic,
    count: int = 12,
    seed: int = 1,
    samples: int = 200_000,
    max_checked: int = 3000,
) -> PoseSet:
    """``count`` well-spread, reachable, collision-free poses whose ball the camera sees.

    Raises:
        ThinkfastError: fewer than ``count`` candidates (the camera sees too little of the
            arm's workspace from where it is, or too few samples).
    """
    rng = np.random.default_rng(seed)
    q, p, f = candidate_poses(robot, camera, rng, samples=samples)
    if len(q) > max_checked:
        keep = spread_subset(p, max_checked)
        q, p, f = q[keep], p[keep], f[keep]
    checker = CollisionChecker(robot, Kinematics(robot))
    free = np.array([not checker.in_collision(x) for x in q], dtype=bool)
    q, p, f = q[free], p[free], f[free]
    if len(q) < count:
        raise ThinkfastError(
            f"only {len(q)} collision-free poses with the ball in view out of {samples} samples "
            f"(wanted {count}): draw more (--samples) or check the camera pose"
        )
    pick = spread_subset(p, count)
    order = pick[tour_from(robot.home, q[pick])]
    return PoseSet(q[order], p[order], f[order])


def simulate_camera_record(
    robot: Robot,
    qs: np.ndarray,
    truth: CameraExtrinsic,
    rng: np.random.Generator,
    *,
    frames: int = 25,
    model: CameraModelConfig = CameraModelConfig(),
    ball_offset: np.ndarray | None = None,
    t0: float = 1.7e9,
    pose_period: float = 5.0,
) -> list[CalibPose]:
    """Detections of the shield-mounted ball at poses ``qs`` (P, 6) by a camera at ``truth``.

    Per pose ``frames`` frames at ``model.rate`` (the arm at rest): each a dropout (two-state
    chain), a gross outlier (``outlier_prob``) or an inlier with the stereo noise of
    :func:`thinkfast.sim.camera.measure`; the disparity noise is drawn once for the record. A
    ball outside the image gets no detections.
    """
    kin = Kinematics(robot)
    offset = default_ball_offset(robot) if ball_offset is None else np.asarray(ball_offset)
    R, c = truth.rotation(), truth.translation()
    sigma_disp = rng.uniform(*model.disparity_sigma)
    out = []
    for i, q in enumerate(np.atleast_2d(qs)):
        T = kin.fk(q, robot.shield_link)
        p_cam = ((T[:3, 3] + T[:3, :3] @ offset - c) @ R)[None].repeat(frames, axis=0)
        stamps = t0 + i * pose_period + np.arange(frames) / model.rate
        if not in_view(p_cam[:1], model)[0]:
            out.append(CalibPose(np.array(q, dtype=float), np.zeros(0), np.zeros((0, 3))))
            continue
        seen = ~dropout_mask(frames, model, rng)
        outlier = rng.random(frames) < model.outlier_prob
        meas = np.where(
            outlier[:, None], gross_error(p_cam, model, rng), measure(p_cam, sigma_disp, model, rng)
        )
        out.append(CalibPose(np.array(q, dtype=float), stamps[seen], meas[seen]))
    return out
