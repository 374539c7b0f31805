"""Primitive checks: the motion bound between checks holds for real points of the robot."""

from __future__ import annotations

import numpy as np

from thinkfast.compile.pathcheck import PathChecker, step_motion
from thinkfast.robot.batch_collision import sphere_cover
from thinkfast.robot.steering import Steering


def test_step_motion_bounds_the_motion_of_every_point(robot, checker):
    """Points sampled inside every link's collision shapes never move farther than the bound."""
    pc = PathChecker(robot, 0.02, 0.0, 0.002)
    rng = np.random.default_rng(11)
    q = robot.home + np.cumsum(rng.normal(0, 0.02, (200, 6)), axis=0)
    poses = pc.batch.fk.link_poses(q)
    bound = step_motion(poses, pc.extent)
    for shape in robot.shapes:
        centres, radii = sphere_cover(shape)
        local = centres[rng.integers(len(centres), size=50)] + rng.normal(
            0, 0.3 * radii.min(), (50, 3)
        )
        pts = local @ shape.T_link_shape[:3, :3].T + shape.T_link_shape[:3, 3]
        P = poses[shape.link]
        world = pts @ P[:, :3, :3].transpose(0, 2, 1) + P[:, None, :3, 3]
        moved = np.linalg.norm(np.diff(world, axis=0), axis=2).max(axis=1)
        assert np.all(moved <= bound + 1e-12), shape.link


def test_checks_are_spaced_by_at_most_the_resolution(robot):
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    traj = steer.steer(np.r_[robot.home[:3], np.zeros(6)], robot.home[:3] + [0.5, 0.3, -0.2])
    coarse = PathChecker(robot, 0.04, 0.01, 0.002).check(traj, traj.duration, robot.home[3:])
    fine = PathChecker(robot, 0.01, 0.01, 0.002).check(traj, traj.duration, robot.home[3:])
    assert coarse.ok and fine.ok
    assert fine.checks >= 3 * coarse.checks  # 4x finer resolution, about 4x the checks


def test_position_limits_are_enforced_along_the_primitive(robot):
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    start = np.r_[robot.home[:3], np.zeros(6)]
    target = robot.home[:3].copy()
    target[1] = robot.q_upper[1] - 0.005  # inside the URDF limit, outside the 0.01 margin
    res = PathChecker(robot, 0.02, 0.01, 0.002).check(
        steer.steer(start, target), 5.0, robot.home[3:]
    )
    assert not res.ok and res.reason in ("position_limit", "collision")


def test_check_many_equals_one_primitive_at_a_time(robot):
    """Batched checking (groups, refinement rounds, stacked collision checks) gives each
    primitive the result it gets alone: valid ones, a limit, a collision, a resting one."""
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    pc = PathChecker(robot, 0.02, 0.01, 0.002)
    rng = np.random.default_rng(26)
    start = np.r_[robot.home[:3], np.zeros(6)]
    targets = [robot.home[:3] + rng.uniform(-0.8, 0.8, 3) for _ in range(14)]
    targets.append(np.array([0.0, 1.6, 0.5]))  # through the floor
    high = robot.home[:3].copy()
    high[1] = robot.q_upper[1] - 0.005  # inside the URDF limit, outside the margin
    targets += [high, robot.home[:3]]
    trajs = [steer.steer(start, g) for g in targets]
    spans = [min(t.duration, 0.1) if k % 3 == 0 else t.duration for k, t in enumerate(trajs)]
    wrists = np.tile(robot.home[3:], (len(trajs), 1))
    many = pc.check_many(trajs, spans, wrists)
    one = [pc.check(t, s, w) for t, s, w in zip(trajs, spans, wrists, strict=True)]
    for a, b in zip(many, one, strict=True):
        assert (a.ok, a.reason, a.checks, a.detail) == (b.ok, b.reason, b.checks, b.detail)
        assert np.array_equal(a.wrist_end, b.wrist_end)
    reasons = {r.reason for r in many}
    assert "" in reasons and len(reasons) >= 2
