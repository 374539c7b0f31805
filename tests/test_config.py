"""Bad configuration and robot files: one line naming the file and the problem, non-zero exit."""

from __future__ import annotations

import shutil
from dataclasses import dataclass

import pytest

from tests.conftest import DEFAULT_CONFIG, ROBOT_TOML, assert_one_line_error, run_cli
from thinkfast.compile.config import load_compile_config
from thinkfast.config import from_dict, spec
from thinkfast.errors import ConfigError, RobotModelError
from thinkfast.robot.model import load_robot


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "body, key, problem",
    [
        ("[goals]\nspacing = 0.15\nspcing = 0.2\n", "goals.spcing", "unknown key"),
        ("[goals]\nspacing = 'wide'\n", "goals.spacing", "expected a number"),
        ("[goals]\nspacing = -0.1\n", "goals.spacing", "must be > 0"),
        ("[goals]\nz_min = 1.0\nz_max = 0.5\n", "goals.z_max", "must be >="),
        ("[plane]\ndistance = 0\n", "plane.distance", "must be > 0"),
        ("plane = 3\n", "plane", "expected a table"),
        ("[goals]\nspacing = nan\n", "goals.spacing", "finite"),
    ],
)
def test_invalid_compile_config_names_the_key(tmp_path, body, key, problem):
    path = _write(tmp_path, "c.toml", f'robot = "{ROBOT_TOML}"\n' + body)
    with pytest.raises(ConfigError) as err:
        load_compile_config(path)
    assert err.value.key == key and problem in str(err.value) and str(path) in str(err.value)


def test_default_config_loads_and_points_at_the_default_robot():
    loaded = load_compile_config(DEFAULT_CONFIG)
    assert loaded.robot_path == ROBOT_TOML.resolve()
    assert len(loaded.sha256) == 64


def test_booleans_are_not_numbers_and_arrays_have_fixed_length():
    @dataclass(frozen=True)
    class C:
        x: float = spec(1.0)
        v: tuple[float, ...] = spec((0.0, 0.0), length=2)

    with pytest.raises(ConfigError, match="x: expected a number"):
        from_dict(C, {"x": True}, "f.toml")
    with pytest.raises(ConfigError, match=r"v: expected 2 values, got 3"):
        from_dict(C, {"v": [1, 2, 3]}, "f.toml")
    with pytest.raises(ConfigError, match=r"v\[1\]: expected a number"):
        from_dict(C, {"v": [1, "a"]}, "f.toml")


@pytest.fixture
def robot_copy(tmp_path):
    """A writable copy of the robot description and a compile config pointing at it."""
    rdir = tmp_path / "robot"
    shutil.copytree(ROBOT_TOML.parent, rdir)
    cfg = _write(tmp_path, "c.toml", f'robot = "{rdir / "robot.toml"}"\n')
    return rdir, cfg


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda d: (d / "irb1600.urdf").unlink(), "URDF file not found"),
        (lambda d: (d / "irb1600.urdf").write_text("<robot><link name="), "malformed URDF"),
        (
            lambda d: (d / "irb1600.urdf").write_text(
                (d / "irb1600.urdf").read_text().replace('radius="0.20"', 'radius="abc"')
            ),
            "cylinder radius",
        ),
        (lambda d: (d / "robot.toml").write_text("name = [\n"), "invalid TOML"),
        (
            lambda d: (d / "robot.toml").write_text(
                (d / "robot.toml").read_text().replace("max_jerk", "max_jrek")
            ),
            "max_jrek: unknown key",
        ),
        (
            lambda d: (d / "robot.toml").write_text(
                (d / "robot.toml").read_text().replace('"joint_6"]', '"joint_7"]')
            ),
            "do not match",
        ),
        (lambda d: (d / "robot.toml").unlink(), "robot.toml: file not found"),
    ],
)
def test_broken_robot_files_give_one_line_errors(robot_copy, mutate, needle):
    rdir, cfg = robot_copy
    mutate(rdir)
    with pytest.raises((ConfigError, RobotModelError), match=needle):
        load_robot(rdir / "robot.toml")
    proc = run_cli("thinkfast-compile", "goals", str(cfg))
    assert_one_line_error(proc, needle, str(rdir))


def test_missing_and_malformed_config_via_cli(tmp_path):
    assert_one_line_error(
        run_cli("thinkfast-compile", "goals", str(tmp_path / "nope.toml")), "nope.toml", "not found"
    )
    bad = _write(tmp_path, "bad.toml", "[goals\n")
    assert_one_line_error(
        run_cli("thinkfast-compile", "goals", str(bad)), "bad.toml", "invalid TOML"
    )
    assert_one_line_error(run_cli("thinkfast-compile", "nosuchcommand"), "nosuchcommand")


def test_every_command_has_help():
    for args in (
        ("thinkfast-compile", "--help"),
        ("thinkfast-compile", "goals", "--help"),
        ("thinkfast-run", "--help"),
    ):
        proc = run_cli(*args)
        assert proc.returncode == 0 and "Usage" in proc.stdout
