"""The scene's pure geometry (ellipsoids that reproduce a covariance, the crossing flat on the
plane) and its Foxglove entities (real foxglove-sdk messages, real kinematics), as both live
views and the MCAP export draw them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thinkfast.view.scene import (
    ENTITY_IDS,
    Scene,
    _quat_from_x,
    ellipsoid,
    matrix_quat,
    plane_cov,
    scene_schema,
)


def test_the_ellipsoid_reproduces_the_covariance():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.01 * np.eye(3)
    half, quat = ellipsoid(cov, sigmas=2.0)
    r = Rotation.from_quat(quat).as_matrix()
    np.testing.assert_allclose(r @ np.diag((half / 2.0) ** 2) @ r.T, cov, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(matrix_quat(r)).as_matrix(), r, atol=1e-12)


def test_a_degenerate_or_broken_covariance_still_gives_a_finite_ellipsoid():
    half, quat = ellipsoid(np.array([[np.nan, 0, 0], [0, -1e-3, 0], [0, 0, 4.0]]), sigmas=1.0)
    assert np.isfinite(half).all() and np.isfinite(quat).all()
    assert sorted(half) == pytest.approx([0.0, 0.0, 2.0])
    assert np.linalg.norm(quat) == pytest.approx(1.0)


def test_the_crossing_covariance_lies_flat_on_the_plane():
    o_cov = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, 0.003], [0.002, 0.003, 1e-4]])
    c = plane_cov(o_cov, thickness=1e-6)
    assert c[0, 0] == 1e-6 and not c[0, 1:].any() and not c[1:, 0].any()
    np.testing.assert_array_equal(c[1:, 1:], o_cov[:2, :2])


def test_the_arrow_turns_x_onto_the_velocity():
    rng = np.random.default_rng(5)
    for u in [*rng.normal(size=(20, 3)), (1.0, 0, 0), (-1.0, 0, 0)]:
        u = np.asarray(u, dtype=float) / np.linalg.norm(u)
        np.testing.assert_allclose(Rotation.from_quat(_quat_from_x(u)).apply([1.0, 0, 0]), u,
                                   atol=1e-9)  # fmt: skip


@pytest.fixture(scope="module")
def scene(robot):
    pytest.importorskip("foxglove")
    return Scene(robot, 0.8, np.array([[0.0, 1.0], [0.15, 1.15]]))


def decoded(scene, entity):
    """``entity`` as a client sees it: encoded by the SDK, decoded with protobuf from the
    schema's FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    schema = scene_schema()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(bytes(schema.data)).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return cls.FromString(scene.update([entity])).entities[0]


def test_the_shield_is_drawn_where_the_kinematics_put_it(scene, robot):
    from thinkfast.robot.kinematics import Kinematics

    q = robot.home + np.array([0.3, -0.2, 0.1, 0.0, 0.4, 0.0])
    e = decoded(scene, scene.arm("measured", q))
    pose = Kinematics(robot).shield(q)
    c = e.cylinders[0]
    p = c.pose.position
    np.testing.assert_allclose([p.x, p.y, p.z], pose.centre, atol=1e-9)
    o = c.pose.orientation  # the cylinder's axis (its z) is the shield's normal
    axis = Rotation.from_quat([o.x, o.y, o.z, o.w]).apply([0.0, 0.0, 1.0])
    assert abs(float(np.dot(axis, pose.normal))) == pytest.approx(1.0, abs=1e-9)
    assert c.size.x == pytest.approx(2 * robot.shield_radius) and e.id == "arm_measured"
    assert len(e.lines[0].points) == len(scene.frames)


def test_belief_crossing_and_plan_entities(scene):
    mean = np.array([4.0, 0.1, 1.5, -9.0, 0.2, 2.0])
    cov = np.diag([4e-4, 1e-4, 9e-4, 1.0, 1.0, 1.0])
    ball = decoded(scene, scene.ball(mean, cov))
    centre = ball.spheres[1].pose.position
    assert [centre.x, centre.y, centre.z] == pytest.approx(mean[:3].tolist())
    assert sorted([ball.spheres[1].size.x, ball.spheres[1].size.y, ball.spheres[1].size.z]) == (
        pytest.approx([0.04, 0.08, 0.12])  # diameters: 2 x 2 sigma
    )
    assert ball.arrows[0].shaft_length == pytest.approx(0.08 * np.linalg.norm(mean[3:]))
    cross = decoded(scene, scene.crossing(np.array([0.2, 1.1, 0.35]), np.diag([0.01, 0.04, 1e-4])))
    s = cross.spheres[0]
    p = s.pose.position
    assert (p.x, p.y, p.z) == pytest.approx((0.8, 0.2, 1.1))
    assert min(s.size.x, s.size.y, s.size.z) < 0.01  # flat on the plane
    assert "in 0.350 ± 0.010 s" == cross.texts[0].text
    path = np.array([[0.8, 0, 1], [0.8, 0.1, 1.1]])
    plan = decoded(scene, scene.plan("executing: direct move to goal 1", 1, path))
    g = plan.spheres[0].pose.position
    assert (g.x, g.y, g.z) == pytest.approx((0.8, 0.15, 1.15)) and len(plan.lines[0].points) == 2
    goals = decoded(scene, scene.goals())
    assert len(goals.spheres) == 2 and goals.spheres[1].pose.position.y == pytest.approx(0.15)
    assert {e.id for e in (ball, cross, plan, goals)} <= set(ENTITY_IDS)
    assert Scene(scene.robot, 0.8, None).goals() is None
