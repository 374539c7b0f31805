"""Every robot folder (robots/*/) loads through ``load_robot`` and its URDF says what its README
says: the zero configuration, the OPW parameters, the joint_3 offset, the reach and the limits
table. The figures are read from each README, so a number mistyped in either file fails here; and
every compile config (trees/*.toml) starts its tree from a home on its plane, facing the ball, at
the centre of its protected region."""

from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np
import pytest

from thinkfast.compile.config import load_compile_config
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import load_robot

ROOT = Path(__file__).resolve().parents[1]
ROBOT_TOMLS = sorted(ROOT.glob("robots/*/robot.toml"))
TREE_CONFIGS = sorted(ROOT.glob("trees/*.toml"))
NUM = r"([-+]?\d+(?:\.\d+)?)"

params = pytest.mark.parametrize("toml", ROBOT_TOMLS, ids=lambda p: p.parent.name)


@functools.cache
def loaded(toml: Path):
    """The robot, its kinematics and its README (whitespace collapsed to single spaces)."""
    robot = load_robot(toml)
    return robot, Kinematics(robot), " ".join((toml.parent / "README.md").read_text().split())


def readme_numbers(text: str, pattern: str, what: str) -> list[float]:
    m = re.search(pattern, text)
    assert m, f"README states no {what} (pattern {pattern!r})"
    return [float(g) for g in m.groups()]


def limits_table(toml: Path) -> dict[int, tuple[float, float, float, float, float]]:
    """README's limits table: joint -> (lower deg, upper deg, deg/s, rad/s^2, rad/s^3)."""
    rows = {}
    cell = r"\s*([^|]*?)\s*\|"
    for line in (toml.parent / "README.md").read_text().splitlines():
        m = re.match(r"\|\s*([1-6])\s*\|" + cell * 4, line)
        if not m:
            continue
        joint, pos, vel, acc, jerk = m.groups()
        if pos.startswith("+-"):
            hi = float(pos[2:].split()[0])
            lo = -hi
        else:
            lo, hi = (float(x) for x in pos.split()[0].split(".."))
        rows[int(joint)] = (lo, hi, *(float(c.split()[0]) for c in (vel, acc, jerk)))
    return rows


def opw_fk(p: dict[str, float], q: np.ndarray):
    """Wrist centre and flange position by the OPW closed form (Brandstoetter et al. 2014);
    joint_3 carries the URDF's -pi/2 offset (OPW zero: forearm along the lower arm)."""
    q1, q2, q3, q4, q5, q6 = q
    q3 = q3 + np.pi / 2
    k = np.hypot(p["a2"], p["c3"])
    psi3 = np.arctan2(p["a2"], p["c3"])
    cx1 = p["c2"] * np.sin(q2) + k * np.sin(q2 + q3 + psi3) + p["a1"]
    cz1 = p["c2"] * np.cos(q2) + k * np.cos(q2 + q3 + psi3)
    c1, s1 = np.cos(q1), np.sin(q1)
    wrist = np.array([cx1 * c1 - p["b"] * s1, cx1 * s1 + p["b"] * c1, cz1 + p["c1"]])

    def rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])

    def ry(a):
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1.0, 0], [-np.sin(a), 0, np.cos(a)]])

    R = rz(q1) @ ry(q2 + q3) @ rz(q4) @ ry(q5) @ rz(q6)
    return wrist, wrist + p["c4"] * R[:, 2]


def test_the_robot_folders_are_there():
    names = {p.parent.name for p in ROBOT_TOMLS}
    assert {"irb1600", "irb1600_6_120", "irb2600_12_165"} <= names


@params
def test_loads_and_passes_its_checks(toml):
    robot, kin, _ = loaded(toml)  # load_robot runs toml_checks: a refusal raises here
    urdf = robot.urdf_path.read_text()
    assert f'<robot name="{robot.name}">' in urdf
    assert "<mesh" not in urdf  # primitive envelopes only
    assert robot.joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    assert np.all(robot.v_max <= robot.model.velocityLimit)
    assert np.all((robot.q_lower <= robot.home) & (robot.home <= robot.q_upper))
    assert robot.shield_radius == 0.20 and robot.shield_thickness == 0.01
    assert np.allclose(kin.fk(np.zeros(6), "shield")[:3, 3] - kin.placement("tool0")[:3, 3],
                       [0.055, 0.0, 0.0], atol=1e-12)  # fmt: skip
    assert CollisionChecker(robot, kin).collisions(robot.home) == []


@params
def test_zero_configuration_is_where_the_readme_says(toml):
    _, kin, text = loaded(toml)
    v = readme_numbers(
        text, rf"wrist centre \({NUM}, {NUM}, {NUM}\) and flange \({NUM}, {NUM}, {NUM}\) at zero",
        "zero-configuration wrist centre and flange",
    )  # fmt: skip
    kin.update(np.zeros(6))
    assert np.allclose(kin.placement("link_5")[:3, 3], v[:3], atol=1e-9, rtol=0)
    flange = kin.placement("tool0")
    assert np.allclose(flange[:3, 3], v[3:], atol=1e-9, rtol=0)
    assert np.allclose(flange[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)  # flange normal +x


@params
def test_fk_matches_the_readme_opw_parameters(toml):
    robot, kin, text = loaded(toml)
    names = ("a1", "a2", "b", "c1", "c2", "c3", "c4")
    pattern = r"OPW closed form \(" + ", ".join(f"{n} {NUM}" for n in names) + r"\)"
    p = dict(zip(names, readme_numbers(text, pattern, "OPW parameters"), strict=True))
    rng = np.random.default_rng(7)
    for q in rng.uniform(robot.q_lower, robot.q_upper, size=(200, 6)):
        wrist, flange = opw_fk(p, q)
        kin.update(q)
        assert np.allclose(kin.placement("link_5")[:3, 3], wrist, atol=1e-9, rtol=0)
        assert np.allclose(kin.placement("tool0")[:3, 3], flange, atol=1e-9, rtol=0)


@params
def test_joint_3_offset_and_reach_are_the_readme_figures(toml):
    robot, kin, text = loaded(toml)
    (offset,) = readme_numbers(text, rf"joint_3 \(y\) {NUM} above joint_2", "joint_3 offset")
    j3 = next(j for j in robot.chain if j.name == "joint_3")
    assert np.allclose(j3.T_parent_joint[:3, 3], [0.0, 0.0, offset], atol=1e-12, rtol=0)
    (reach,) = readme_numbers(
        text, rf"Reach \(axis 1 to the wrist centre, arm stretched out\): {NUM} m", "reach"
    )
    # Farthest wrist centre from axis 1: the lower arm horizontal (joint_2 = 90 deg) and the
    # forearm in line with it (joint_3 searched over its range, twice refined).
    lo, hi = robot.q_lower[2], robot.q_upper[2]
    best = 0.0
    for _ in range(3):
        qs = np.linspace(lo, hi, 201)
        dist = []
        for q3 in qs:
            kin.update(np.array([0.0, np.pi / 2, q3, 0.0, 0.0, 0.0]))
            dist.append(np.hypot(*kin.placement("link_5")[:2, 3]))
        i = int(np.argmax(dist))
        best = dist[i]
        lo, hi = qs[max(i - 1, 0)], qs[min(i + 1, len(qs) - 1)]
    assert abs(best - reach) < 5e-4  # the README rounds to the millimetre


@params
def test_limits_are_the_readme_table(toml):
    robot, _, _ = loaded(toml)
    rows = limits_table(toml)
    assert sorted(rows) == [1, 2, 3, 4, 5, 6], "README limits table: one row per joint"
    lo, hi, vel, acc, jerk = (
        np.array(c) for c in zip(*(rows[j] for j in range(1, 7)), strict=True)
    )
    assert np.allclose(robot.q_lower, np.radians(lo), atol=1e-9, rtol=0)
    assert np.allclose(robot.q_upper, np.radians(hi), atol=1e-9, rtol=0)
    assert np.allclose(robot.v_max, np.radians(vel), atol=1e-9, rtol=0)
    assert np.allclose(robot.model.velocityLimit, np.radians(vel), atol=1e-9, rtol=0)
    np.testing.assert_array_equal(robot.a_max, acc)
    np.testing.assert_array_equal(robot.j_max, jerk)


def test_every_robot_folder_has_a_tree_config():
    named = {load_compile_config(c).robot_path for c in TREE_CONFIGS}
    assert {t.resolve() for t in ROBOT_TOMLS} <= named


@pytest.mark.parametrize("config", TREE_CONFIGS, ids=lambda p: p.stem)
def test_home_is_on_the_plane_at_the_centre_of_the_protected_region(config):
    cfg = load_compile_config(config)
    _, kin, _ = loaded(cfg.robot_path)
    robot = kin.robot
    pose = kin.shield(robot.home)
    g = cfg.config.goals
    centre = [cfg.config.plane.distance, (g.y_min + g.y_max) / 2, (g.z_min + g.z_max) / 2]
    assert np.allclose(pose.centre, centre, atol=1e-6, rtol=0)
    assert np.allclose(pose.normal, [1.0, 0.0, 0.0], atol=1e-6)
    assert robot.home[5] == 0.0
