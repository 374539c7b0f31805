"""Shield paths from joint motions (thinkfast.robot.shield_path) agree with the full FK."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from thinkfast.control.segments import Steering
from thinkfast.errors import RobotModelError
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.shield_path import ShieldSampler, sample_joint_paths
from thinkfast.robot.wrist import CoplanarWrist


def test_centres_equal_the_full_fk_with_the_coplanar_wrist_to_1e12(robot):
    """The wrist-centre shortcut against FK of all six joints, the wrist from the coplanar rule
    (either branch, any joint_6), along random continuous paths."""
    rng = np.random.default_rng(1)
    fk, wrist, sampler = BatchFK(robot), CoplanarWrist(robot), ShieldSampler(robot)
    for _ in range(10):
        a = robot.home[:3] + rng.uniform(-0.8, 0.8, 3)
        b = robot.home[:3] + rng.uniform(-0.8, 0.8, 3)
        q123 = a + np.linspace(0, 1, 80)[:, None] * (b - a)
        prev = robot.home[3:] + [rng.choice([0.0, np.pi]), 0.0, rng.uniform(-3, 3)]
        q = np.column_stack([q123, wrist.solve(q123, prev)])
        pose = fk.link_poses(q, until=robot.shield_link)[robot.shield_link]
        assert np.max(np.abs(sampler.centres(q123) - pose[:, :3, 3])) < 1e-12
        assert np.allclose(pose[:, :3, 2], [1.0, 0.0, 0.0], atol=1e-9)


def test_a_tilted_normal_moves_the_centre_as_the_full_fk_does(robot):
    rng = np.random.default_rng(2)
    normal = np.array([np.cos(0.4), 0.0, np.sin(0.4)])
    fk, sampler = BatchFK(robot), ShieldSampler(robot)
    q123 = robot.home[:3] + rng.uniform(-0.5, 0.5, (30, 3))
    w = np.array([CoplanarWrist(robot, normal).solve(x[None], robot.home[3:])[0] for x in q123])
    pose = fk.link_poses(np.column_stack([q123, w]), until=robot.shield_link)[robot.shield_link]
    assert np.allclose(pose[:, :3, 2], normal, atol=1e-9)
    assert np.max(np.abs(sampler.centres(q123, normal) - pose[:, :3, 3])) < 1e-12


def test_centres_keep_any_leading_shape(robot):
    q = robot.home[:3] + np.random.default_rng(3).uniform(-0.3, 0.3, (4, 7, 3))
    c = ShieldSampler(robot).centres(q)
    assert c.shape == (4, 7, 3)
    assert np.allclose(c[2, 5], ShieldSampler(robot).centres(q[2, 5]))


def test_centre_rows_equal_centres_bit_for_bit(robot, kernel_choice):
    """The row layout the chooser packs (x, y, z rows) computes the same values as
    :meth:`ShieldSampler.centres`, element for element, into a given array (numpy rows and
    the compiled row pass alike)."""
    q = robot.home[:3] + np.random.default_rng(4).uniform(-1.0, 1.0, (500, 3))
    sampler = ShieldSampler(robot)
    assert sampler._plan is not None  # this robot's chain can take the compiled row pass
    out = np.full((6, 500), np.nan)
    got = sampler.centre_rows(q, out=out[:3])
    assert np.shares_memory(got, out)
    assert np.array_equal(out[:3], sampler.centres(q).T)
    assert np.isnan(out[3:]).all()
    assert np.array_equal(sampler.centre_rows(q[:1]), sampler.centres(q[:1]).T)


def test_joint_paths_follow_ruckig_and_hold_both_ends(robot):
    steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
    start = np.r_[robot.home[:3], np.zeros(6)]
    trajs = [steer.to_rest(start, robot.home[:3] + d) for d in ([0.4, -0.2, 0.1], [0, 0, 0])]
    times = np.linspace(-0.1, 1.5, 33)
    q = sample_joint_paths(trajs, times)
    assert q.shape == (2, 33, 3)
    inside = (times >= 0) & (times <= trajs[0].duration)
    for t, row in zip(times[inside], q[0, inside], strict=True):
        assert np.allclose(row, trajs[0].at_time(float(t))[0], atol=1e-12)
    assert np.allclose(q[0, 0], robot.home[:3]) and np.allclose(
        q[0, -1], robot.home[:3] + [0.4, -0.2, 0.1]
    )
    assert np.allclose(q[1], robot.home[:3])  # a zero-length move: at rest throughout


def test_a_shield_off_the_wrist_axis_is_refused(robot):
    chain = list(robot.chain)
    i = next(k for k, j in enumerate(chain) if j.child == robot.shield_link)
    T = chain[i].T_parent_joint.copy()
    T[0, 3] += 0.05  # 5 cm sideways in the flange frame
    chain[i] = dataclasses.replace(chain[i], T_parent_joint=T)
    with pytest.raises(RobotModelError, match="shield"):
        ShieldSampler(dataclasses.replace(robot, chain=tuple(chain)))
