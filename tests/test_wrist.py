"""The coplanar wrist rule keeps the shield facing +x and moves continuously."""

from __future__ import annotations

import numpy as np

from thinkfast.robot.wrist import CoplanarWrist


def test_shield_normal_is_plus_x_along_random_paths(robot, kin):
    wrist = CoplanarWrist(robot)
    rng = np.random.default_rng(10)
    for _ in range(20):
        a = robot.home[:3] + rng.uniform(-0.8, 0.8, 3)
        b = robot.home[:3] + rng.uniform(-0.8, 0.8, 3)
        q123 = a + np.linspace(0, 1, 150)[:, None] * (b - a)
        w = wrist.solve(q123, robot.home[3:])
        for n in range(0, 150, 15):
            assert np.allclose(kin.shield(np.r_[q123[n], w[n]]).normal, [1, 0, 0], atol=1e-9)


def test_starts_on_the_branch_of_the_previous_wrist_and_stays_continuous(robot):
    wrist = CoplanarWrist(robot)
    q123 = robot.home[:3] + np.linspace(0, 1, 200)[:, None] * np.array([0.5, 0.2, -0.3])
    w = wrist.solve(q123, robot.home[3:])
    assert np.allclose(w[0], robot.home[3:], atol=1e-9)
    assert np.max(np.abs(np.diff(w, axis=0))) < 0.05  # away from the singularity: smooth
    flipped = wrist.solve(q123, robot.home[3:] + [np.pi, 0, 0])
    assert np.allclose(flipped[0, :2], [robot.home[3] + np.pi, -robot.home[4]], atol=1e-9)


def test_solve_paths_is_solve_on_each_path_bit_for_bit(robot):
    """Many paths in one call (through the singularity, across +-pi) equal one call each."""
    wrist = CoplanarWrist(robot)
    rng = np.random.default_rng(23)
    paths, prevs = [], []
    for k in range(40):
        n = int(rng.integers(1, 60))
        start = rng.uniform(robot.q_lower[:3], robot.q_upper[:3])
        step = rng.normal(0.0, 0.05 if k % 2 else 0.4, (n, 3))  # odd: smooth, even: jumpy
        paths.append(start + np.cumsum(step, axis=0))
        prevs.append(rng.uniform(-3.0, 3.0, 3))
    counts = np.array([len(p) for p in paths])
    got = wrist.solve_paths(np.vstack(paths), np.cumsum(counts) - counts, np.array(prevs))
    want = np.vstack([wrist.solve(p, q) for p, q in zip(paths, prevs, strict=True)])
    assert np.array_equal(got, want)
