"""Batched collision checking equals fcl on every pair; sphere covers really cover."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.robot.batch_collision import BatchCollision, point_distance, sphere_cover
from thinkfast.robot.model import CollisionShape


@pytest.fixture(scope="module")
def batch(checker):
    return BatchCollision(checker)


def test_batch_agrees_with_scalar_fcl_on_random_configurations(robot, checker, batch):
    q = np.random.default_rng(7).uniform(robot.q_lower, robot.q_upper, size=(1500, 6))
    for n in range(len(q)):
        hit = batch.first_collision(q[n : n + 1])
        assert (hit is not None) == checker.in_collision(q[n])


def test_first_collision_reports_the_earliest_configuration(robot, batch):
    free = np.tile(robot.home, (5, 1))
    bad = np.array([0, 1.6, 0.5, 0, 0, 0.0])  # through the floor
    q = np.vstack([free, bad, free])
    hit = batch.first_collision(q)
    assert hit is not None and hit.index == 5 and "floor" in hit.pair
    assert batch.first_collision(free) is None


def test_lower_bounds_never_exceed_true_distances(robot, checker, batch):
    q = np.random.default_rng(8).uniform(robot.q_lower, robot.q_upper, size=(40, 6))
    lb, _ = batch.lower_bounds(q)
    import fcl

    for n in range(len(q)):
        checker._pose(q[n])
        for p, (i, j) in enumerate(checker.pairs):
            d = fcl.distance(
                checker.objects[i], checker.objects[j], fcl.DistanceRequest(), fcl.DistanceResult()
            )
            assert lb[n, p] <= max(d, 0.0) + 1e-9


@pytest.mark.parametrize(
    "shape, size",
    [
        ("box", (0.66, 0.48, 0.17)),
        ("box", (0.22, 0.14, 0.865)),
        ("cylinder", (0.065, 0.35)),
        ("cylinder", (0.2, 0.01)),
        ("sphere", (0.1,)),
    ],
)
def test_sphere_cover_contains_every_point_of_the_primitive(shape, size):
    s = CollisionShape("x", shape, size, np.eye(4))
    centres, radii = sphere_cover(s)
    rng = np.random.default_rng(9)
    if shape == "box":
        pts = (rng.random((5000, 3)) - 0.5) * np.array(size)
    elif shape == "cylinder":
        r = size[0] * np.sqrt(rng.random(5000))
        a = rng.random(5000) * 2 * np.pi
        z = (rng.random(5000) - 0.5) * size[1]
        pts = np.column_stack([r * np.cos(a), r * np.sin(a), z])
        pts[:8] = [
            [size[0] * np.cos(x), size[0] * np.sin(x), size[1] / 2]
            for x in np.linspace(0, 2 * np.pi, 8)
        ]  # the rim, the hardest place to cover
    else:
        d = rng.normal(size=(5000, 3))
        pts = size[0] * d / np.linalg.norm(d, axis=1)[:, None]
    inside = np.linalg.norm(pts[:, None] - centres[None], axis=2) <= radii[None] + 1e-9
    assert inside.any(axis=1).all()
    assert np.all(point_distance(s, pts) <= 1e-12)


def test_suspects_are_the_pairs_whose_lower_bound_is_not_positive(robot, batch):
    """The coarse sphere per pair only skips pairs the sphere-by-sphere bound clears too."""
    rng = np.random.default_rng(24)
    q = np.vstack([
        rng.uniform(robot.q_lower, robot.q_upper, size=(600, 6)),
        robot.home + np.cumsum(rng.normal(0.0, 0.05, (200, 6)), axis=0),
    ])  # fmt: skip
    lb, poses = batch.lower_bounds(q)
    rows, cols = batch.suspects(poses, len(q))
    want_rows, want_cols = np.nonzero(lb <= 0.0)
    assert len(want_rows) > 100
    assert np.array_equal(rows, want_rows) and np.array_equal(cols, want_cols)


def test_first_collisions_of_stacked_paths_equal_one_path_at_a_time(robot, batch):
    rng = np.random.default_rng(25)
    paths = [rng.uniform(robot.q_lower, robot.q_upper, size=(int(n), 6)) for n in (1, 7, 30, 3)]
    paths.append(np.tile(robot.home, (4, 1)))
    counts = np.array([len(p) for p in paths])
    hits = batch.first_collisions(np.vstack(paths), np.cumsum(counts) - counts)
    assert hits == [batch.first_collision(p) for p in paths]
    assert any(h is not None for h in hits) and hits[-1] is None
