"""Home belongs to the cell: robot.toml's is checked on the plane, a missing one is solved by IK
for the region's centre, and the tree carries it to every command that runs it."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROBOT_TOML, SMALL_TREE, compile_cached
from thinkfast.errors import ConfigError

REGION = "[goals]\ny_min = -0.3\ny_max = 0.6\nz_min = 0.5\nz_max = 1.4\nspacing = 0.3\n"


def _robot_without_home(directory):
    """A copy of the default robot folder whose robot.toml gives no home."""
    folder = directory / "nohome"
    shutil.copytree(ROBOT_TOML.parent, folder, ignore=shutil.ignore_patterns("controller"))
    toml = folder / "robot.toml"
    toml.write_text(re.sub(r"(?m)^home = .*$", "", toml.read_text()))
    return toml


def _config(directory, robot, body: str):
    path = directory / "cell.toml"
    path.write_text(f'robot = "{robot}"\n{body}')
    return path


@pytest.fixture(scope="module")
def solved_tree(tmp_path_factory):
    """A small tree of a robot without a home, for an off-centre region."""
    d = tmp_path_factory.mktemp("solved")
    config = _config(d, _robot_without_home(d), f"{REGION}[tree]\nmax_depth = 1\n")
    return compile_cached(config, d / "solved.h5")


def test_a_robot_without_a_home_gets_one_solved_at_the_regions_centre(solved_tree):
    from thinkfast.compile.home import home_error
    from thinkfast.robot.kinematics import Kinematics
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.provenance import Provenance
    from thinkfast.tree.robot_match import robot_for_tree

    tree = load_tree(solved_tree)
    home = Provenance.of(tree.meta).home
    assert home is not None and len(home) == 6
    robot = robot_for_tree(tree.meta, str(solved_tree))
    assert robot.home_solved and np.array_equal(robot.home, home)
    assert np.allclose(tree.node_state[0, :3], home[:3], atol=1e-12)  # the root is that home
    shield = Kinematics(robot).shield(robot.home)
    assert np.allclose(shield.centre, [0.8, 0.15, 0.95], atol=1e-6)  # the region's centre
    assert np.allclose(shield.normal, [1.0, 0.0, 0.0], atol=1e-6)
    assert max(home_error(robot, robot.home, 0.8)) < 1e-6
    assert home[5] == 0.0


def test_the_simulated_controller_starts_at_a_solved_home(solved_tree):
    """``thinkfast-sim controller --tree`` takes the arm's start from the tree, not robot.toml
    (which gives none: without --tree it refuses, naming robot.toml)."""
    from thinkfast.errors import RobotModelError
    from thinkfast.sim.irc5_cli import controller_cell
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.provenance import Provenance

    robot, servo, _ = controller_cell(solved_tree, None, None)
    assert np.array_equal(robot.home, Provenance.of(load_tree(solved_tree).meta).home)
    from thinkfast.robot.model import load_robot

    bare = load_robot(robot.toml_path)
    assert bare.home is None
    with pytest.raises(RobotModelError, match="gives no home"):
        bare.require_home()


def test_a_given_home_off_the_plane_is_refused_with_the_distance(tmp_path):
    """The default robot's home, made for the plane at 0.8 m, stands 13 mm off a plane at
    0.813 m (the 1.2 m arm's case): refused naming the key, the distance and the fix."""
    from tests.conftest import run_cli
    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.home import check_home, home_error, placed_robot

    config = _config(tmp_path, ROBOT_TOML, "[plane]\ndistance = 0.813\n[goals]\nspacing = 0.5\n")
    loaded = load_compile_config(config)
    with pytest.raises(ConfigError, match=r"tree\.home.*13\.0 mm off the plane.*solve"):
        check_home(placed_robot(loaded), loaded.config, str(loaded.path))
    out = tmp_path / "t.h5"
    proc = run_cli("thinkfast-compile", "tree", str(config), "-o", str(out), "--jobs", "1")
    assert proc.returncode == 1 and not out.exists()
    assert "tree.home" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    ok = _config(tmp_path, ROBOT_TOML, '[plane]\ndistance = 0.813\n[tree]\nhome = "solve"\n')
    robot = placed_robot(load_compile_config(ok))
    assert robot.home_solved and max(home_error(robot, robot.home, 0.813)) < 1e-6


def test_a_home_on_the_plane_is_kept_and_the_default_tree_is_unchanged():
    """robot.toml's home on the default plane is the tree's home, read, not solved: the tree's
    parameters hold no ``home`` (nor ``tree.home``), so its fingerprint is the one before."""
    import json

    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.home import placed_robot, solve_home

    loaded = load_compile_config(ROBOT_TOML.parents[2] / "trees" / "irb1600_default.toml")
    robot = placed_robot(loaded)
    assert not robot.home_solved
    params = loaded.parameters(robot)
    assert "home" not in params and "home" not in params["tree"]
    json.dumps(params)
    # the solve reproduces the hand-typed home (to the IK's tolerance)
    assert np.allclose(solve_home(robot, loaded.config), robot.home, atol=1e-7)


def test_no_home_in_reach_is_refused_naming_the_region(tmp_path):
    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.home import placed_robot

    far = '[goals]\ny_min = 2.5\ny_max = 3.0\nspacing = 0.3\n[tree]\nhome = "solve"\n'
    with pytest.raises(ConfigError, match=r"goals.*no home.*region's centre"):
        placed_robot(load_compile_config(_config(tmp_path, ROBOT_TOML, far)))


def test_throws_for_a_tree_aim_at_its_region(solved_tree):
    """The thrower aims at the tree's protected region, not the default one."""
    from thinkfast.sim.cli_options import load_throws, tree_cell
    from thinkfast.sim.throws import plane_crossing

    _, _, plane = tree_cell(solved_tree)
    assert (plane.aim_y, plane.aim_z) == ((-0.3, 0.6), (0.5, 1.4))
    throws = load_throws(40, 5, None, "still=1", 0, plane)
    ys, zs = zip(*((c.y, c.z) for c in map(plane_crossing, throws)), strict=True)
    assert -0.3 - 1e-6 <= min(ys) and max(ys) <= 0.6 + 1e-6
    assert 0.5 - 1e-6 <= min(zs) and max(zs) <= 1.4 + 1e-6
    assert max(ys) - min(ys) > 0.5  # spread over it, not stuck at a point


def test_verify_checks_a_solved_home_tree(solved_tree):
    from tests.conftest import run_cli

    out = run_cli("thinkfast-compile", "verify", str(solved_tree), "--jobs", "1")
    assert out.returncode == 0 and "verify: OK" in out.stdout, out.stdout + out.stderr


def test_the_small_tree_template_still_reads_home_from_robot_toml(tmp_path):
    """The default family (robot.toml gives a home on the plane) compiles as before."""
    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.home import placed_robot

    text = SMALL_TREE.format(robot=ROBOT_TOML, spacing=0.3, depth=1, subgoal=0.6, radius=0.3)
    robot = placed_robot(load_compile_config(_config(tmp_path, ROBOT_TOML, text.split("\n", 1)[1])))
    assert not robot.home_solved


def test_calibration_takes_the_trees_robot_and_home_in_base(solved_tree, tmp_path):
    """``thinkfast-calib --tree``: the tree's robot with its solved home, in ``base`` (the
    camera is calibrated in the robot's frame); another robot beside the tree is refused."""
    from thinkfast.calib.cli import _robot
    from thinkfast.errors import RobotModelError
    from thinkfast.tree.file import load_meta
    from thinkfast.tree.provenance import Provenance

    robot = _robot(None, solved_tree)
    assert robot.placement is None
    assert np.array_equal(robot.home, Provenance.of(load_meta(solved_tree)).home)
    with pytest.raises(RobotModelError, match="another robot than the tree's"):
        _robot(ROBOT_TOML, solved_tree)


def test_the_kit_of_a_solved_home_tree_homes_the_arm_there(solved_tree, tmp_path):
    """``thinkfast-compile kit ROBOT --tree T``: the RAPID module's TF_HOME is the tree's
    home; the simulated controller refuses a kit that homes elsewhere (the daemon would find
    the arm away from home) and caps joint speeds at the kit's EGM_MAX_SPEED_DEV."""
    from tests.conftest import run_cli
    from thinkfast.compile.kit import read_kit
    from thinkfast.sim.irc5_cli import controller_cell
    from thinkfast.tree.file import load_meta
    from thinkfast.tree.provenance import Provenance

    home = np.array(Provenance.of(load_meta(solved_tree)).home)
    toml = Path(load_meta(solved_tree)["config_path"]).parent / "nohome" / "robot.toml"
    kit = tmp_path / "kit"
    proc = run_cli(
        "thinkfast-compile", "kit", str(toml), "--tree", str(solved_tree), "-o", str(kit)
    )
    assert proc.returncode == 0, proc.stderr
    got = read_kit(kit)
    assert np.max(np.abs(np.array(got.home) - home)) < 1e-6
    robot, servo, _ = controller_cell(solved_tree, None, None, kit)
    assert max(servo.v_max) <= got.max_speed_deviation + 1e-12
    assert min(servo.v_max) == pytest.approx(min(robot.v_max), abs=2e-8)  # rounded down only
    other = tmp_path / "default_kit"
    run_cli("thinkfast-compile", "kit", str(ROBOT_TOML), "-o", str(other))
    with pytest.raises(ConfigError, match=r"TF_HOME.*away from home.*--tree"):
        controller_cell(solved_tree, None, None, other)
