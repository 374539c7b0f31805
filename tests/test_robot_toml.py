"""robot.toml is validated against its URDF when it is loaded: a limit typed in degrees, above the
URDF's or implausible, a home outside the limits, an unknown link or a list of the wrong length is
refused with one line naming robot.toml, the key, the value and the fix (thinkfast/robot/
toml_checks.py). The real robot loads unchanged."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from tests.conftest import ROBOT_TOML, assert_one_line_error, run_cli
from thinkfast.errors import ConfigError
from thinkfast.robot import toml_checks
from thinkfast.robot.model import load_robot

DATA_SHEET_DEG_S = [180, 180, 185, 385, 400, 460]  # the IRB 1600's velocities, deg/s


@pytest.fixture
def robot_dir(tmp_path):
    """A writable copy of robots/irb1600."""
    rdir = tmp_path / "robot"
    shutil.copytree(ROBOT_TOML.parent, rdir)
    return rdir


def edit(rdir, key: str, value: str, file: str = "robot.toml"):
    """robot.toml (or ``file``) in ``rdir`` with the line starting ``key =`` set to ``value``."""
    path = rdir / file
    lines = path.read_text().splitlines()
    hits = [i for i, line in enumerate(lines) if line.startswith(f"{key} =")]
    assert len(hits) == 1, key
    lines[hits[0]] = f"{key} = {value}"
    path.write_text("\n".join(lines) + "\n")
    return rdir / "robot.toml"


def refusal(path) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        load_robot(path)
    assert err.value.source == str(path)
    assert "\n" not in str(err.value)
    return err.value


def test_the_real_robot_loads_with_its_values():
    robot = load_robot(ROBOT_TOML)
    np.testing.assert_array_equal(robot.v_max, np.radians(DATA_SHEET_DEG_S))
    np.testing.assert_array_equal(robot.v_max, robot.model.velocityLimit)  # at the URDF's
    assert robot.a_max[0] == 12.0 and robot.j_max[5] == 400.0 and robot.home[0] == 0.0


def test_velocities_typed_in_deg_s_are_refused_with_the_rad_s_value(robot_dir):
    path = edit(robot_dir, "max_velocity", str(DATA_SHEET_DEG_S))
    err = refusal(path)
    assert err.key == "max_velocity[0]"
    assert err.problem == (
        "180 rad/s is above joint_1's URDF limit 3.14159 rad/s (<limit velocity> in "
        "irb1600.urdf); looks like deg/s; robot.toml takes rad/s: 3.14 for 180 deg/s"
    )
    readme = " ".join((ROBOT_TOML.parent / "README.md").read_text().split())
    assert f"robot.toml: max_velocity[0]: {err.problem}" in readme  # the README quotes it


def test_the_deg_hint_value_is_within_the_urdf_limit():
    """The suggested rad/s value is rounded down, so following the hint loads (185 deg/s is
    3.2289 rad/s: 3.23 would be refused)."""
    for deg in DATA_SHEET_DEG_S:
        assert float(toml_checks._down(math.radians(deg))) <= math.radians(deg)
    assert toml_checks._down(math.radians(185)) == "3.22"


def test_a_velocity_above_the_urdf_is_refused_with_the_urdf_value(robot_dir):
    v = [3.141592653589793, 3.141592653589793, 3.3, 6.719517620178169, 6.981317007977318, 8.0]
    err = refusal(edit(robot_dir, "max_velocity", str(v)))
    assert err.key == "max_velocity[2]"
    assert "3.3 rad/s is above joint_3's URDF limit 3.22886 rad/s" in err.problem
    assert err.problem.endswith("robot.toml may only lower it: set at most 3.22885")
    assert "deg" not in err.problem


def test_a_velocity_below_the_urdf_loads(robot_dir):
    robot = load_robot(edit(robot_dir, "max_velocity", "[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]"))
    assert robot.v_max.tolist() == [1.0] * 6


def test_without_a_urdf_velocity_the_plausibility_bound_applies(robot_dir):
    urdf = robot_dir / "irb1600.urdf"
    urdf.write_text(urdf.read_text().replace('velocity="3.141592653589793"', 'velocity="0"', 1))
    err = refusal(edit(robot_dir, "max_velocity", str(DATA_SHEET_DEG_S)))
    assert err.key == "max_velocity[0]"
    assert err.problem.startswith(
        "180 rad/s is above the plausibility bound 30 rad/s; joint_1's URDF <limit velocity> is 0"
    )
    assert err.problem.endswith("robot.toml takes rad/s: 3.14 for 180 deg/s")


@pytest.mark.parametrize(
    "key, value, where, problem",
    [
        ("max_acceleration", "[-12.0, 12, 15, 30, 30, 40]", "max_acceleration[0]", "must be > 0"),
        ("max_acceleration", "[12.0, 0, 15, 30, 30, 40]", "max_acceleration[1]", "must be > 0"),
        ("max_jerk", "[120, 120, 150, 300, 300, inf]", "max_jerk[5]", "finite"),
        (
            "max_acceleration",
            "[687.5, 687.5, 859.4, 1719, 1719, 2292]",
            "max_acceleration[0]",
            "687.5 rad/s^2 is above the plausibility bound 200 rad/s^2; looks like deg/s^2; "
            "robot.toml takes rad/s^2: 12 for 687.5 deg/s^2",
        ),
        (
            "max_jerk",
            "[120, 120, 150, 300, 300, 22918]",
            "max_jerk[5]",
            "22918 rad/s^3 is above the plausibility bound 5000 rad/s^3; looks like deg/s^3; "
            "robot.toml takes rad/s^3: 400 for 22918 deg/s^3",
        ),
    ],
)
def test_bad_accelerations_and_jerks_are_refused_naming_the_key(
    robot_dir, key, value, where, problem
):
    err = refusal(edit(robot_dir, key, value))
    assert err.key == where and problem in err.problem


@pytest.mark.parametrize(
    "home, where, problem",
    [
        (
            "[0.0, -3.33, 21.3, 0.0, -18.0, 0.0]",
            "home[1]",
            "-3.33 rad is outside joint_2's URDF limits [-1.571, 2.094] rad; degrees? robot.toml "
            "takes rad: -0.0581 for -3.33 deg",
        ),
        (
            "[0.0, 0.0, 0.0, 0.0, 2.1, 0.0]",
            "home[4]",
            "2.1 rad is outside joint_5's URDF limits [-2.007, 2.007] rad; choose a home inside",
        ),
        ("[0.0, 0.0, 0.0, 0.0, nan, 0.0]", "home[4]", "expected a finite number, got nan"),
    ],
)
def test_a_home_outside_the_limits_is_refused_naming_the_joint(robot_dir, home, where, problem):
    err = refusal(edit(robot_dir, "home", home))
    assert err.key == where and problem in err.problem


@pytest.mark.parametrize("key", ["home", "max_velocity", "max_acceleration", "max_jerk"])
def test_a_per_joint_list_of_the_wrong_length_is_refused(robot_dir, key):
    err = refusal(edit(robot_dir, key, "[1.0, 1.0, 1.0, 1.0, 1.0]"))
    assert err.key == key
    assert err.problem == (
        "expected 6 values, one per joint of joints (joint_1, joint_2, joint_3, joint_4, "
        "joint_5, joint_6), got 5"
    )


def test_a_missing_shield_link_is_refused_listing_the_candidates(robot_dir):
    err = refusal(edit(robot_dir, "shield_link", '"shild"'))
    assert err.key == "shield_link"
    assert err.problem.startswith("'shild' is not a link of irb1600.urdf; name the link")
    assert err.problem.endswith("with one cylinder: link_4, link_5, link_6, tool0, shield)")


def test_an_allowed_collision_with_an_unknown_link_is_refused(robot_dir):
    err = refusal(edit(robot_dir, "allowed_collisions", '[["link_4", "link_6"], ["link_4", "t0"]]'))
    assert err.key == "allowed_collisions[1]"
    assert err.problem == "['link_4', 't0'] must name two links ('t0' not in irb1600.urdf)"


def test_check_config_refuses_a_deg_s_robot_in_one_line(robot_dir, tmp_path):
    """``thinkfast-run --check-config`` loads the robot its run config names (``robot``), so the
    daemon's own start-up check refuses the robot.toml before a tree is read."""
    path = edit(robot_dir, "max_velocity", str(DATA_SHEET_DEG_S))
    run = tmp_path / "run.toml"
    run.write_text(f'robot = "{path}"\n')
    proc = run_cli("thinkfast-run", "--check-config", str(run))
    assert proc.returncode == 1 and proc.stdout == ""
    assert_one_line_error(
        proc, "thinkfast-run: error:", f"{path}: max_velocity[0]: 180 rad/s", "3.14 for 180 deg/s"
    )


def test_the_robots_sizes_come_from_robot_toml(robot_dir):
    robot = load_robot(ROBOT_TOML)
    assert (robot.n_joints, robot.n_arm) == (6, 3)
    toml = robot_dir / "robot.toml"
    toml.write_text(f"positioning_joints = 3\n{toml.read_text()}")  # before the tables
    assert load_robot(toml).n_arm == 3


@pytest.mark.parametrize("value", ["2", "6", "0"])
def test_an_unsupported_positioning_split_is_refused_naming_the_key(robot_dir, value):
    toml = robot_dir / "robot.toml"
    toml.write_text(f"positioning_joints = {value}\n{toml.read_text()}")
    with pytest.raises(ConfigError, match="positioning_joints") as err:
        load_robot(toml)
    assert str(toml) in str(err.value) and "\n" not in str(err.value)
