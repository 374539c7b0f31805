"""docs/ROBOTS.md, followed with no code edit: a toy robot folder (another arm length and slower
joints, no home) and a turned plane with an offset, flown through the compiler, the lockstep
bench and the real-time daemon, each on the toy's own cell."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from tests.conftest import ROBOT_TOML, compile_cached

YAW, OFFSET = math.radians(30.0), 0.25
REACH = 0.62  # m: joint_3 above joint_2 (the IRB 1600-10/1.45 has 0.70)


def _edit(text: str, *pairs: tuple[str, str]) -> str:
    for old, new in pairs:
        assert text.count(old) == 1, old  # the template changed: follow it
        text = text.replace(old, new)
    return text


def make_toy_robot(directory):
    """A robot folder as docs/ROBOTS.md builds one: URDF, robot.toml, no code."""
    folder = directory / "toy_arm"
    folder.mkdir()
    drop = 0.7 - REACH  # the upper arm's envelope follows the arm
    urdf = _edit(
        (ROBOT_TOML.parent / "irb1600.urdf").read_text(),
        ('<robot name="abb_irb1600_10_145">', '<robot name="toy_arm">'),
        ('<origin xyz="0 0 0.7" rpy="0 0 0"/>', f'<origin xyz="0 0 {REACH}" rpy="0 0 0"/>'),
        ('<origin xyz="-0.01 -0.18 0.3425"', f'<origin xyz="-0.01 -0.18 {0.3425 - drop / 2}"'),
        ('<box size="0.22 0.14 0.865"/>', f'<box size="0.22 0.14 {0.865 - drop}"/>'),
    )
    (folder / "toy.urdf").write_text(urdf)
    toml = _edit(
        ROBOT_TOML.read_text(),
        ('name = "abb_irb1600_10_145"', 'name = "toy_arm"'),
        ('urdf = "irb1600.urdf"', 'urdf = "toy.urdf"'),
    )
    toml = re.sub(r"(?m)^home = .*$", "", toml)  # the compiler solves it for the cell
    toml = re.sub(r"(?m)^max_velocity = .*$",
                  "max_velocity = [2.0, 2.0, 2.5, 5.0, 5.0, 6.0]", toml)  # fmt: skip
    (folder / "robot.toml").write_text(toml)
    return folder / "robot.toml"


CELL = """robot = "{robot}"
[plane]
distance = 0.75
yaw = {yaw!r}
offset = {offset!r}
[goals]
y_min = -0.6
y_max = 0.6
z_min = 0.4
z_max = 1.4
spacing = 0.3
[tree]
max_depth = 1
"""


@pytest.fixture(scope="module")
def toy_tree(tmp_path_factory):
    d = tmp_path_factory.mktemp("toy")
    robot = make_toy_robot(d)
    config = d / "toy_cell.toml"
    config.write_text(CELL.format(robot=robot, yaw=YAW, offset=OFFSET))
    return compile_cached(config, d / "toy_cell.h5")


def test_the_toy_cell_compiles_for_its_robot_plane_and_solved_home(toy_tree):
    from tests.conftest import run_cli
    from thinkfast.robot.kinematics import Kinematics
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.provenance import Provenance
    from thinkfast.tree.robot_match import robot_for_tree

    tree = load_tree(toy_tree)
    prov = Provenance.of(tree.meta)
    assert tree.meta["robot_name"] == "toy_arm"
    assert (prov.plane.yaw, prov.plane.offset) == (YAW, OFFSET)
    robot = robot_for_tree(tree.meta, str(toy_tree))
    assert robot.name == "toy_arm" and robot.v_max[0] == 2.0
    home = Kinematics(robot).shield(robot.home)  # at the region's centre, in the plane's frame
    assert np.allclose(home.centre, [0.75, 0.0, 0.9], atol=1e-6)
    assert np.allclose(home.normal, [1.0, 0.0, 0.0], atol=1e-6)
    proc = run_cli("thinkfast-compile", "verify", str(toy_tree), "--jobs", "1")
    assert proc.returncode == 0 and "verify: OK" in proc.stdout, proc.stdout + proc.stderr


def test_the_toy_cell_flies_the_lockstep_bench_on_its_own_arm(toy_tree, tmp_path):
    """``thinkfast-sim bench`` names the toy's cell in its JSON, aims at its region, and the
    oracle (the toy arm's physics) bounds both planners."""
    from tests.conftest import run_cli

    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(toy_tree), "--throws", "16", "--feints", "0",
        "--seed", "4", "--planners", "tree,naive,oracle", "-j", "1", "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    cell = out["cell"]
    assert cell["robot"] == "toy_arm"
    assert cell["plane"]["yaw"] == YAW and cell["plane"]["offset"] == OFFSET
    assert cell["region"] == {"y": [-0.6, 0.6], "z": [0.4, 1.4]}
    blocked = {k: v["blocked"] for k, v in out["planners"].items()}
    assert blocked["tree"] > 0
    assert blocked["oracle"] >= max(blocked["tree"], blocked["naive"]), blocked


@pytest.mark.realtime
def test_the_toy_cell_runs_through_the_real_time_daemon(toy_tree, tmp_path):
    """The real daemon and a simulated controller on the toy's cell: the daemon starts with the
    toy's robot, the simulated arm starts at the tree's (solved) home, the arm moves for a
    throw, and every throw is judged on the turned plane. (Whether a throw is blocked depends
    on this host's clock; that it is judged at all, on this cell, does not.)"""
    from thinkfast.control.config import RunConfig
    from thinkfast.record.format import read_record
    from thinkfast.record.tables import columns, record_plane
    from thinkfast.sim.cli_options import load_throws, tree_cell
    from thinkfast.sim.realtime import run_with_daemon

    _, robot, plane = tree_cell(toy_tree, RunConfig())
    throws = load_throws(2, 6, None, "still=1", 0, plane)
    record = tmp_path / "toy.h5"
    lines = []
    results = run_with_daemon(toy_tree, "tree", robot, throws, 6, RunConfig().camera,
                              record=record, report=lines.append)  # fmt: skip
    assert len(results) == 2 and all(r.why for r in results), lines
    rec = read_record(record)
    assert rec.attrs["robot_name"] == "toy_arm"
    assert record_plane(rec).yaw == YAW
    q_fb = columns(rec, "egm")["q_fb"]
    assert np.allclose(q_fb[0], robot.home, atol=2e-3)  # the arm started at the tree's home
    assert np.ptp(q_fb[:, :3], axis=0).max() > 0.05  # and moved for the throws
