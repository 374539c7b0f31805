"""Forward kinematics of the URDF against an independent closed form (OPW parameters)."""

from __future__ import annotations

import numpy as np

# OPW parameters of the IRB 1600-10/1.45 (docs/FACTS.md); joint_3 carries a -pi/2 offset in OPW.
A1, C1, C2, C3, C4 = 0.150, 0.4865, 0.700, 0.600, 0.065


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def opw_fk(q):
    """Wrist centre, flange position and flange rotation by the OPW closed form (a2 = b = 0)."""
    q1, q2, q3, q4, q5, q6 = q
    q3 = q3 + np.pi / 2  # OPW zero: forearm along the lower arm
    cx1 = C2 * np.sin(q2) + C3 * np.sin(q2 + q3) + A1
    cz1 = C2 * np.cos(q2) + C3 * np.cos(q2 + q3)
    wrist = np.array([cx1 * np.cos(q1), cx1 * np.sin(q1), cz1 + C1])
    R = _rz(q1) @ _ry(q2 + q3) @ _rz(q4) @ _ry(q5) @ _rz(q6)
    return wrist, wrist + C4 * R[:, 2], R


def test_fk_matches_opw_closed_form_on_1000_random_configurations(robot, kin):
    rng = np.random.default_rng(1)
    for q in rng.uniform(robot.q_lower, robot.q_upper, size=(1000, 6)):
        wrist, flange, R = opw_fk(q)
        kin.update(q)
        assert np.allclose(kin.placement("link_5")[:3, 3], wrist, atol=1e-9, rtol=0)
        T = kin.placement("tool0")
        assert np.allclose(T[:3, 3], flange, atol=1e-9, rtol=0)
        assert np.allclose(T[:3, :3], R, atol=1e-9, rtol=0)


def test_zero_configuration_matches_the_data_sheet_geometry(kin):
    kin.update(np.zeros(6))
    assert np.allclose(kin.placement("link_5")[:3, 3], [0.75, 0.0, 1.1865], atol=1e-12)
    flange = kin.placement("tool0")
    assert np.allclose(flange[:3, 3], [0.815, 0.0, 1.1865], atol=1e-12)
    assert np.allclose(flange[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)  # flange normal +x


def test_shield_sits_55_mm_out_along_the_flange_normal(robot, kin):
    rng = np.random.default_rng(2)
    for q in rng.uniform(robot.q_lower, robot.q_upper, size=(50, 6)):
        flange = kin.fk(q, "tool0")
        pose = kin.shield(q)
        assert np.allclose(pose.normal, flange[:3, 2], atol=1e-12)
        assert np.allclose(pose.centre, flange[:3, 3] + 0.055 * flange[:3, 2], atol=1e-12)
    assert robot.shield_radius == 0.20 and robot.shield_thickness == 0.01


def test_shield_jacobians_match_central_finite_differences(robot, kin):
    rng = np.random.default_rng(3)
    h = 1e-6
    for q in rng.uniform(robot.q_lower, robot.q_upper, size=(20, 6)):
        _, Jp, Jn = kin.shield_jacobian(q)
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            plus, minus = kin.shield(q + dq), kin.shield(q - dq)
            assert np.allclose(Jp[:, j], (plus.centre - minus.centre) / (2 * h), atol=1e-7)
            assert np.allclose(Jn[:, j], (plus.normal - minus.normal) / (2 * h), atol=1e-7)


def test_home_puts_the_shield_on_the_plane_facing_the_ball(robot, kin):
    pose = kin.shield(robot.home)
    assert abs(pose.centre[0] - 0.8) < 1e-6
    assert np.allclose(pose.normal, [1.0, 0.0, 0.0], atol=1e-6)
