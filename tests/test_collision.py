"""Self and cell collision: known colliding configurations are caught, home is free."""

from __future__ import annotations

import numpy as np
import pytest


def test_home_is_collision_free_with_clearance(robot, checker):
    assert checker.collisions(robot.home) == []
    assert checker.min_distance(robot.home).distance > 0.01


@pytest.mark.parametrize(
    "q, expected",
    [
        ([0, 0, -3.9, 0, 0, 0], ("link_1", "shield")),  # forearm folded back over the base
        ([0, 0, 0, 0, 2.0, 0], ("link_4", "shield")),  # wrist folded: shield into the forearm
        ([0, 1.6, 0.5, 0, 0, 0], ("shield", "floor")),  # reaching down through the floor
        ([0, 0.9, 1.1, 0, 0, 0], ("shield", "camera_mount")),  # into the camera pedestal
    ],
)
def test_known_collisions_are_detected_and_named(checker, q, expected):
    q = np.array(q, dtype=float)
    hits = checker.collisions(q)
    assert expected in hits or expected[::-1] in hits, hits
    assert checker.in_collision(q)
    assert checker.min_distance(q).distance == 0.0


def test_adjacent_links_are_never_checked(robot, checker):
    pairs = {frozenset((checker.names[i], checker.names[j])) for i, j in checker.pairs}
    for child, parent in robot.link_parent.items():
        if parent:
            assert frozenset((child, parent)) not in pairs
    assert frozenset(("link_4", "shield")) in pairs  # the shield can hit the forearm


def test_prefilter_never_hides_a_collision(robot, checker):
    """in_collision (bounding-sphere prefilter) agrees with exhaustive fcl distance queries."""
    rng = np.random.default_rng(4)
    for q in rng.uniform(robot.q_lower, robot.q_upper, size=(300, 6)):
        assert checker.in_collision(q) == (checker.min_distance(q).distance == 0.0)


def test_min_distance_grows_as_the_arm_leaves_the_floor(checker):
    low = checker.min_distance(np.array([0, 1.2, 0.5, 0, 0, 0.0]))
    high = checker.min_distance(np.array([0, 0.9, 0.5, 0, 0, 0.0]))
    assert high.distance > low.distance
