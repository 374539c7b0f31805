"""Batched numpy FK equals Pinocchio."""

from __future__ import annotations

import numpy as np

from thinkfast.robot.batch_fk import BatchFK


def test_batched_fk_matches_pinocchio_on_every_link(robot, kin):
    q = np.random.default_rng(5).uniform(robot.q_lower, robot.q_upper, size=(300, 6))
    poses = BatchFK(robot).link_poses(q)
    assert set(poses) >= {"base_link", "link_1", "link_6", "tool0", "shield"}
    for n in range(len(q)):
        kin.update(q[n])
        for link, P in poses.items():
            assert np.allclose(P[n], kin.placement(link), atol=1e-12), link


def test_until_stops_early_but_agrees(robot):
    q = np.random.default_rng(6).uniform(robot.q_lower, robot.q_upper, size=(20, 6))
    fk = BatchFK(robot)
    part = fk.link_poses(q, until="link_3")
    assert "link_4" not in part
    assert np.array_equal(part["link_3"], fk.link_poses(q)["link_3"])
