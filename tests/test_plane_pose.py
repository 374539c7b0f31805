"""A plane with a pose: the plane frame, the robot placed in it, detections moved into it, and a
turned plane flown through the compiler and the lockstep bench."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from thinkfast.contract.detection import DetectionLimits
from thinkfast.contract.frames import CameraExtrinsic, PlanePose
from thinkfast.control.intake import Intake
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import default_robot_path, load_robot
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.robot.wrist import CoplanarWrist

TURNED = PlanePose(0.8, math.radians(30.0), 0.25, 0.0)
PEDESTAL = PlanePose(0.8, 0.0, -0.1, 0.4)


def test_the_plane_frame_turns_and_moves_base_points_and_back():
    p = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.0]])
    q = TURNED.to_plane(p)
    c, s = math.cos(TURNED.yaw), math.sin(TURNED.yaw)
    assert np.allclose(q[0], [c, -s - 0.25, 0.5])  # the normal (c, s, 0) of base is plane x
    assert np.allclose(TURNED.to_base(q), p)
    assert np.allclose(PEDESTAL.to_plane(p)[0], [1.0, 0.1, 0.9])
    assert PlanePose().to_plane(p) is not None and np.array_equal(PlanePose().to_plane(p), p)


def test_a_camera_posed_in_the_plane_sees_the_same_camera_coordinates():
    e = CameraExtrinsic((0.46, 0.1, 0.3), (0.02, -0.1, 0.3))
    inside = TURNED.camera(e)
    ball = np.array([3.0, 0.4, 1.2])  # base
    in_cam = (ball - np.array(e.xyz)) @ e.rotation()
    in_cam_plane = (TURNED.to_plane(ball) - np.array(inside.xyz)) @ inside.rotation()
    assert np.allclose(in_cam, in_cam_plane, atol=1e-12)


@pytest.mark.parametrize("plane", [TURNED, PEDESTAL], ids=["turned", "pedestal"])
def test_every_kinematics_of_a_placed_robot_is_in_the_plane_frame(plane):
    robot = load_robot(default_robot_path())
    placed = robot.placed(plane)
    rng = np.random.default_rng(4)
    q123 = np.array(robot.home[:3]) + rng.normal(0.0, 0.3, (16, 3))
    wrist = CoplanarWrist(placed).solve(q123, np.array(robot.home[3:]))
    q = np.column_stack([q123, wrist])
    T = plane.matrix()
    kin, kin0 = Kinematics(placed), Kinematics(robot)
    fk = BatchFK(placed).link_poses(q)["shield"]
    for i in range(len(q)):
        M = kin.fk(q[i], "shield")
        assert np.allclose(M, T @ kin0.fk(q[i], "shield"), atol=1e-12)
        assert np.allclose(fk[i], M, atol=1e-12)
        assert np.allclose(kin.shield(q[i]).normal, [1.0, 0.0, 0.0], atol=1e-9)  # faces the ball
    sampler = ShieldSampler(placed)
    assert np.allclose(sampler.centres(q123), fk[:, :3, 3], atol=1e-12)
    assert np.array_equal(sampler.centre_rows(q123).T, sampler.centres(q123))
    # the cell moves with the base: the home pose is as free of collisions as unplaced
    assert CollisionChecker(placed).in_collision(robot.home) == CollisionChecker(
        robot
    ).in_collision(robot.home)


def test_a_plane_without_a_pose_changes_no_number():
    robot = load_robot(default_robot_path())
    same = robot.placed(PlanePose(1.0))
    assert same.model is robot.model and same.chain is robot.chain
    assert same.placement == PlanePose(1.0)
    with pytest.raises(Exception, match="placed in a plane already"):
        same.placed(TURNED)


def test_the_intake_moves_camera_and_base_detections_into_the_plane_frame():
    cam = CameraExtrinsic((0.46, 0.0, 0.3), (0.0, 0.0, 0.0))
    intake = Intake(cam, DetectionLimits(), plane=TURNED)
    got_cam = intake.take(
        json.dumps({"stamp": 10.0, "position": [2.0, 0.1, 0.5], "seq": 1}).encode(), None
    )
    got_base = intake.take(
        json.dumps(
            {"stamp": 10.1, "position": [2.0, 0.1, 0.5], "frame": "base", "seq": 2}
        ).encode(),
        None,
    )
    assert np.allclose(got_cam.position, TURNED.to_plane(np.array([2.46, 0.1, 0.8])))
    assert np.allclose(got_base.position, TURNED.to_plane(np.array([2.0, 0.1, 0.5])))


def test_a_turned_plane_compiles_and_flies_the_lockstep_bench_in_its_frame(tmp_path):
    from thinkfast.compile.build import compile_tree
    from thinkfast.compile.config import load_compile_config
    from thinkfast.control.config import RunConfig
    from thinkfast.sim.bench import run_bench, summarize
    from thinkfast.sim.bench_cli import WorldFactory
    from thinkfast.sim.cli_options import load_throws
    from thinkfast.tree.file import save_tree
    from thinkfast.tree.provenance import Provenance

    config = tmp_path / "turned.toml"
    config.write_text(
        f'robot = "{default_robot_path()}"\n[plane]\ndistance = 0.8\nyaw = {TURNED.yaw!r}\n'
        f"offset = {TURNED.offset!r}\n[goals]\nspacing = 0.3\n[tree]\nmax_depth = 1\n"
        'home = "solve"\n'
    )
    tree = compile_tree(load_compile_config(config))
    assert Provenance.of(tree.meta).plane == TURNED
    kin = Kinematics(load_robot(default_robot_path()).placed(TURNED))
    for q, yz in zip(
        tree.goal_q, tree.goal_yz, strict=True
    ):  # goals on the turned plane, facing the ball
        s = kin.shield(q)
        assert np.allclose(s.centre, [0.8, *yz], atol=1e-6)
        assert np.allclose(s.normal, [1.0, 0.0, 0.0], atol=1e-6)
    path = tmp_path / "turned.h5"
    save_tree(tree, path)
    world = WorldFactory(path, RunConfig())
    throws = load_throws(24, 3, None, None, 0, (0.8, str(path)))
    out = run_bench(world, throws, ("tree", "oracle"), 3, jobs=1)
    rates = {k: v["blocked"] for k, v in summarize(out, ("tree", "oracle"))["planners"].items()}
    assert rates["tree"] > 0 and rates["oracle"] >= rates["tree"], rates
