"""Any cell: every command that meets a tree flies the tree's robot at the tree's plane, or
refuses in one line naming both (thinkfast/tree/robot_match.py)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from tests.conftest import (
    ROBOT_TOML,
    SMALL_TREE,
    assert_one_line_error,
    compile_cached,
    compile_small_tree,
    run_cli,
)

PLANE = 1.0


@pytest.fixture(scope="module")
def tree_08(tmp_path_factory):
    """The small test tree (the default robot, the plane at 0.8 m)."""
    return compile_small_tree(tmp_path_factory.mktemp("cell08"))


@pytest.fixture(scope="module")
def tree_10(tmp_path_factory):
    """The small test tree compiled for the plane x = 1.0 m."""
    d = tmp_path_factory.mktemp("cell10")
    text = SMALL_TREE.format(robot=ROBOT_TOML, spacing=0.3, depth=2, subgoal=0.6, radius=0.3)
    config = d / "plane10.toml"
    config.write_text(f'{text}home = "solve"\n[plane]\ndistance = {PLANE}\n')
    return compile_cached(config, d / "plane10.h5")


@pytest.fixture(scope="module")
def other_robot(tmp_path_factory):
    """robots/irb1600 copied, joint_1's velocity limit lowered: another robot.toml hash."""
    d = tmp_path_factory.mktemp("other") / "irb1600"
    shutil.copytree(ROBOT_TOML.parent, d)
    toml = d / "robot.toml"
    text = toml.read_text()
    head, sep, tail = text.partition("max_velocity = [")
    first, comma, rest = tail.partition(",")
    toml.write_text(f"{head}{sep}{float(first) * 0.9!r}{comma}{rest}")
    return toml


@pytest.fixture(scope="module")
def other_config(tmp_path_factory, other_robot):
    path = tmp_path_factory.mktemp("runcfg") / "run.toml"
    path.write_text(f'robot = "{other_robot}"\n')
    return path


def test_the_trees_robot_is_loaded_and_checked(tree_10):
    from thinkfast.robot.model import load_robot
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.robot_match import check_robot, robot_for_tree

    meta = load_tree(tree_10).meta
    robot = robot_for_tree(meta, str(tree_10))
    assert robot.toml_path.resolve() == ROBOT_TOML.resolve()
    check_robot(meta, load_robot(ROBOT_TOML), str(tree_10))


def test_another_robot_is_refused_naming_both(tree_10, other_robot):
    from thinkfast.errors import RobotModelError
    from thinkfast.robot.model import load_robot
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.robot_match import check_robot

    tree, robot = load_tree(tree_10), load_robot(other_robot)
    with pytest.raises(RobotModelError) as err:
        check_robot(tree.meta, robot, str(tree_10))
    msg = str(err.value)
    assert f"{tree_10} was compiled for {tree.meta['robot_name']}" in msg
    assert tree.meta["robot_toml_sha256"][:12] in msg and robot.toml_sha256[:12] in msg
    assert str(other_robot) in msg and "pass the tree's robot or recompile" in msg


def test_a_lockstep_world_refuses_another_robot(tree_10, other_robot):
    from thinkfast.control.config import RunConfig
    from thinkfast.errors import RobotModelError
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World
    from thinkfast.tree.file import load_tree

    with pytest.raises(RobotModelError, match="compiled for"):
        World(
            load_tree(tree_10), load_robot(other_robot), RunConfig(), ServoConfig(),
            CameraModelConfig(),
        )  # fmt: skip


def test_a_tree_for_a_1m_plane_is_benched_with_throws_judged_at_1m(tree_10):
    """Every throw drawn for the tree crosses x = 1.0 m where it is judged; the bench command
    gives the same counts as the lockstep rows.

    (The oracle is not asserted to bound the tree here: at 1.0 m throw s1-3 crosses at
    (-0.46, 1.62), where the oracle's IK does not converge and it falls back to the nearest goal
    of this coarse tree, too far to reach in time; the tree blocks it with its disk.)"""
    from thinkfast.control.config import RunConfig
    from thinkfast.sim.bench import run_bench
    from thinkfast.sim.bench_cli import WorldFactory
    from thinkfast.sim.cli_options import load_throws, tree_cell
    from thinkfast.sim.throws import ball_state, plane_crossing

    _, _, plane = tree_cell(tree_10, RunConfig())
    assert plane[:2] == (PLANE, str(tree_10))
    throws = load_throws(6, 1, None, None, 0, plane)
    assert [t.plane_x for t in throws] == [PLANE] * 6
    for t in throws:
        p, _ = ball_state(t, plane_crossing(t).t)
        assert p[0] == pytest.approx(PLANE, abs=1e-6)
    world = WorldFactory(tree_10, RunConfig())()
    assert world.tree.plane_x == PLANE
    rows = run_bench(WorldFactory(tree_10, RunConfig()), throws, ["tree", "oracle"], 1, 1)
    blocked = {p: sum(o.blocked for o in rows if o.planner == p) for p in ("tree", "oracle")}
    assert blocked["oracle"] >= 5 and blocked["tree"] >= 5, blocked

    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(tree_10), "--throws", "6", "--feints", "0",
        "--planners", "tree,oracle", "--json", "-j", "1",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)["planners"]
    assert (s["tree"]["blocked"], s["oracle"]["blocked"]) == (blocked["tree"], blocked["oracle"])


def test_a_throw_aimed_at_another_plane_is_refused_by_the_lockstep_core(tree_10):
    from thinkfast.control.config import RunConfig
    from thinkfast.errors import ThinkfastError
    from thinkfast.sim.bench_cli import WorldFactory
    from thinkfast.sim.lockstep import simulate
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    world = WorldFactory(tree_10, RunConfig())()
    throw = sample_throws(ThrowConfig(), 1, 1)[0]  # the model's default plane, 0.8 m
    with pytest.raises(ThinkfastError, match=r"x = 0\.8 m, the tree's is x = 1 m"):
        simulate(world, throw, "tree", 1)


def test_a_throw_set_for_another_plane_is_refused_naming_both(tree_10, tmp_path):
    at08, at10 = tmp_path / "at08.json", tmp_path / "at10.json"
    assert run_cli("thinkfast-sim", "throws", "-o", str(at08), "-n", "2").returncode == 0
    proc = run_cli("thinkfast-sim", "throws", "-o", str(at10), "-n", "2", "--tree", str(tree_10))
    assert proc.returncode == 0, proc.stderr
    assert {t["plane_x"] for t in json.loads(at10.read_text())["throws"]} == {PLANE}
    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(tree_10), "--throw-set", str(at08),
        "--planners", "naive", "--json", "-j", "1",
    )  # fmt: skip
    assert_one_line_error(proc, str(at08), "x = 0.8 m", str(tree_10), "x = 1 m")


def test_bench_refuses_a_run_config_naming_another_robot(tree_08, other_config, other_robot):
    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(tree_08), "--config", str(other_config),
        "--throws", "1", "--planners", "naive", "-j", "1",
    )  # fmt: skip
    assert_one_line_error(proc, f"{tree_08} was compiled for", str(other_robot), "recompile")


def test_the_daemon_refuses_a_run_config_naming_another_robot(tree_08, other_config, other_robot):
    check = run_cli("thinkfast-run", "--check-config", str(other_config), "--tree", str(tree_08))
    assert_one_line_error(check, f"{tree_08} was compiled for", str(other_robot))
    start = run_cli("thinkfast-run", "--tree", str(tree_08), "--config", str(other_config))
    assert_one_line_error(start, f"{tree_08} was compiled for", str(other_robot))
    own = other_config.parent / "own.toml"
    own.write_text(f'robot = "{ROBOT_TOML}"\n')
    ok = run_cli("thinkfast-run", "--check-config", str(own), "--tree", str(tree_08))
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith(f"{own}: OK")


def test_the_short_arm_misses_a_crossing_only_the_long_arm_reaches(tmp_path_factory):
    """The newcomer's case: a ball crossing high in the middle (z 1.75 m on the plane at 0.8 m)
    is blocked by the IRB 1600-10/1.45's oracle and missed by the IRB 1600-6/1.2's, tree and
    oracle alike: the lockstep core, the oracle and the judge use the tree's arm, not the
    default one (before, the 1.2 m arm's tree was flown and judged on the 1.45 m arm)."""
    from thinkfast.control.config import RunConfig
    from thinkfast.sim.bench import run_bench
    from thinkfast.sim.bench_cli import WorldFactory
    from thinkfast.sim.throws import ThrowConfig, make_throw

    short = ROBOT_TOML.parents[1] / "irb1600_6_120" / "robot.toml"
    trees = {
        "1.45": compile_small_tree(tmp_path_factory.mktemp("long"), depth=1),
        "1.2": compile_small_tree(tmp_path_factory.mktemp("short"), robot=short, depth=1),
    }
    throw = make_throw(ThrowConfig(), np.array([7.5, 0.0, 1.6]), (0.0, 1.75), 0.7, 0.5, "high")
    got = {}
    for arm, tree in trees.items():
        rows = run_bench(WorldFactory(tree, RunConfig()), [throw], ["tree", "oracle"], 1, 1)
        got[arm] = {o.planner: o.blocked for o in rows}
    assert got["1.45"]["oracle"], got
    assert not got["1.2"]["oracle"] and not got["1.2"]["tree"], got


def test_a_robot_positioning_with_other_joints_than_the_trees_is_refused(tree_10):
    """The tree's node states hold the robot's positioning joints (``robot.n_arm``): a robot
    whose split differs is refused before any planning."""
    import dataclasses

    from thinkfast.control.config import RunConfig
    from thinkfast.decide.tree_view import runtime_tree
    from thinkfast.errors import RobotModelError
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.robot_match import robot_for_tree

    tree = load_tree(tree_10)
    robot = robot_for_tree(tree.meta, str(tree_10))
    runtime_tree(tree, robot, RunConfig())
    with pytest.raises(RobotModelError, match="plans 3 of 6 joints.*with 2 of 6"):
        runtime_tree(tree, dataclasses.replace(robot, positioning_joints=2), RunConfig())
