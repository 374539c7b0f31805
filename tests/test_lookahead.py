"""Preposterior values: the coming detections' belief, its sigma points, the look-ahead backup."""

import dataclasses

import numpy as np
import pytest

from thinkfast.control.config import RunConfig, default_camera_filter
from thinkfast.control.foresight import foresight
from thinkfast.decide import backup as bk
from thinkfast.decide import lookahead as lk
from thinkfast.decide import values as vl
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.estimate import crossing as delta
from thinkfast.estimate import filter as kf
from thinkfast.tree.file import load_tree

PLANE = 0.8  # m
SENSOR = np.array([0.46, 0.0, 0.3])
RADIUS = 0.2  # m, block radius of the hand-made tree
A, B = (-0.45, 1.0), (0.5, 1.0)  # its two goals [m]


def _model(fps: float = 50.0) -> lk.Foresight:
    return lk.Foresight(default_camera_filter(RunConfig()), SENSOR, 1.0 / fps)


def _ball(spread: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """A ball 5 m out flying at the plane (mean, cov)."""
    mean = np.array([5.8, 0.0, 1.2, -10.0, 0.0, 1.5])
    return mean, np.diag([spread**2] * 3 + [(10 * spread) ** 2] * 3)


def _moments(pts, w, cov):
    """Mean and covariance of the mixture of N(d_k, cov) with weights w."""
    return w @ pts, (pts * w[:, None]).T @ pts + cov


def test_sigma_points_keep_the_spread_and_weights_summing_to_one():
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    spread, future = a @ a.T, 0.1 * b @ b.T
    pts, w, cov = lk.sigma_points(spread, future)
    assert len(pts) == 5 and w.sum() == pytest.approx(1.0) and np.all(w > 0)
    mean, total = _moments(pts, w, cov)
    assert np.allclose(mean, 0.0, atol=1e-12)
    assert np.allclose(total, spread + future, atol=1e-12)
    assert np.allclose(cov[:2], future[:2]) and cov[2, 2] >= future[2, 2]


def test_a_zero_spread_is_one_point_at_the_mean():
    future = np.diag([0.01, 0.02, 0.001])
    pts, w, cov = lk.sigma_points(np.zeros((3, 3)), future)
    assert pts.tolist() == [[0.0, 0.0, 0.0]] and w.tolist() == [1.0]
    assert np.array_equal(cov, future)
    one = np.diag([0.01, 0.0, 0.0])  # one direction with variance: the mean and two points
    pts, w, cov = lk.sigma_points(one, future)
    assert len(pts) == 3 and w.sum() == pytest.approx(1.0)
    assert np.allclose(_moments(pts, w, cov)[1], one + future)


def test_the_future_covariance_is_the_filters_recursion_on_the_predicted_path():
    cfg = dataclasses.replace(
        default_camera_filter(RunConfig()), robust=False, adaptive=False, drag=0.0
    )
    model = lk.Foresight(cfg, SENSOR, 0.02)
    mean, cov = _ball()
    belief = kf.empty(cfg)._replace(t=0.0, t_meas=0.0, mean=mean, cov=cov, n_meas=5)
    n = 4
    m, prior, post = lk.future_state_cov(mean, cov, n, model, belief.r)
    for k in range(1, n + 1):  # the filter fed the noise-free positions of the predicted path
        z = kf.predict(belief, 0.02 * k, cfg).mean[:3]
        belief, _ = kf.update(belief, 0.02 * k, z, cfg, SENSOR)
    assert np.allclose(belief.cov, post, rtol=1e-9, atol=1e-15)
    assert np.allclose(belief.mean, m, atol=1e-9)  # the innovations were zero
    assert np.all(np.linalg.eigvalsh(prior - post) > -1e-15)  # updates only remove variance


def test_no_frame_before_the_commit_means_no_look_ahead():
    mean, cov = _ball()
    today = delta.crossing(mean, cov, PLANE, 9.81).cov
    assert lk.detections_by(0.019, 0.02) == 0 and lk.detections_by(0.1, 0.02) == 5
    assert lk.ahead(mean, cov, today, 0.01, _model(), PLANE) is None


def test_the_coming_frames_split_todays_crossing_into_spread_and_future():
    mean, cov = _ball()
    today = delta.crossing(mean, cov, PLANE, 9.81).cov
    a = lk.ahead(mean, cov, today, 0.1, _model(), PLANE)
    assert a.detections == 5
    assert np.allclose(a.cov + a.spread, today)
    assert np.all(np.linalg.eigvalsh(a.spread) >= -1e-15)
    assert np.all(np.linalg.eigvalsh(a.cov) > 0.0)
    assert lk.lateral_std(a.spread) > 0.01  # 5 frames at 5 m tell a wide belief much
    faster = lk.ahead(mean, cov, today, 0.1, _model(100.0), PLANE)  # more frames, more told
    assert lk.lateral_std(faster.spread) > lk.lateral_std(a.spread)
    assert lk.ahead(mean, cov, today, 0.1, _model(), PLANE, 10.0) is None


def _two_goal_tree():
    """Root 0 with two children: node 1 keeps both goals (terminals to A and B arriving at
    0.30 s), node 2 is committed (one terminal to A arriving at 0.15 s)."""
    goal_yz = np.array([A, B])
    term_goal = np.array([0, 1, 0])
    arrival = np.array([0.30, 0.30, 0.15])
    vlay = vl.layout(goal_yz, term_goal, RADIUS, vl.ValueConfig())
    blay = bk.backup_layout(
        np.array([0, 1, 1]), np.array([1, 3, 3]), np.array([2, 0, 0]),
        np.array([0, 0, 2]), np.array([0, 2, 1]),
    )  # fmt: skip
    return vlay, blay, arrival


def _values(vlay, blay, arrival, mean, cov, ahead=None):
    tv = vl.terminal_values(vlay, mean, cov, arrival)
    back = bk.backup(blay, tv.value, tv.goal_mass)
    if ahead is not None:
        back = lk.lookahead_backup(vlay, blay, back, mean, ahead, arrival, 0)
    return back


def test_a_wide_belief_between_two_goals_values_keeping_both_over_committing():
    vlay, blay, arrival = _two_goal_tree()
    mean = np.array([0.0, 1.0, 0.4])  # between the goals, 0.4 s to go
    cov = np.diag([0.3**2, 0.05**2, 0.05**2])  # wide across them
    qmdp = _values(vlay, blay, arrival, mean, cov)
    assert qmdp.value[2] > qmdp.value[1]  # QMDP: commit towards A (a little nearer the mean)
    future = np.diag([0.03**2, 0.05**2, 0.05**2])  # the coming frames tell the side
    ahead = lk.Ahead(future, cov - future, 5)
    pre = _values(vlay, blay, arrival, mean, cov, ahead)
    assert pre.value[1] > pre.value[2]  # the look-ahead: keep both reachable
    assert pre.value[1] > 1.5 * pre.value[2]
    for v in (pre.value, pre.child_value, pre.term_value):
        assert np.all((v >= 0.0) & (v <= 1.0))
    assert pre.value[0] == pre.value[1] and pre.child_value[0] == pre.value[1]


def test_without_information_to_come_the_look_ahead_is_qmdp():
    vlay, blay, arrival = _two_goal_tree()
    mean = np.array([0.1, 1.1, 0.35])
    cov = np.array([[0.09, 0.01, 0.002], [0.01, 0.04, 0.001], [0.002, 0.001, 0.003]])
    qmdp = _values(vlay, blay, arrival, mean, cov)
    pre = _values(vlay, blay, arrival, mean, cov, lk.Ahead(cov, np.zeros((3, 3)), 3))
    assert np.array_equal(pre.value, qmdp.value)
    assert np.array_equal(pre.child_value, qmdp.child_value)


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, RunConfig())


@pytest.mark.parametrize("spread", [0.005, 0.03, 0.1, 0.3])
@pytest.mark.parametrize("y", [-0.4, 0.0, 0.3])
def test_on_a_compiled_tree_the_values_stay_probabilities(rtree, spread, y):
    mean, cov = _ball(spread)
    mean[1] = y
    c = rtree.crossing(mean, cov, 9.81)
    model = foresight(
        rtree, dataclasses.replace(RunConfig(), value=vl.ValueConfig(backup="lookahead"))
    )
    a = lk.ahead(mean, cov, c.cov, rtree.commit_horizon(0, 0.0, 0.0), model, rtree.plane_x)
    assert a is not None
    d = rtree.decide(c, 0.0, 0.0, 0.004, a)
    q = rtree.decide(c, 0.0, 0.0, 0.004)
    for v in (d.backup.value, d.backup.child_value):
        assert np.all((v >= 0.0) & (v <= 1.0 + 1e-9))
    kids = slice(int(rtree.compiled.child_start[0]), None)
    n = int(rtree.compiled.child_count[0])
    assert np.all(d.backup.value[kids][:n] <= 1.0 + 1e-9)
    assert np.array_equal(d.backup.value[1 + n :], q.backup.value[1 + n :])  # deeper: QMDP
    assert np.array_equal(d.term_value, q.term_value)  # committed edges keep today's value
    assert d.backup.value[0] == max(d.backup.child_value[0], d.backup.term_value[0])


def test_foresight_is_off_with_qmdp_and_follows_the_camera(rtree):
    assert foresight(rtree, RunConfig()) is None
    cfg = RunConfig()
    cfg = dataclasses.replace(
        cfg, value=vl.ValueConfig(backup="lookahead"),
        camera=dataclasses.replace(cfg.camera, fps=40.0),
    )  # fmt: skip
    model = foresight(rtree, cfg)
    assert model.period == pytest.approx(0.025)
    assert np.allclose(model.sensor, rtree.plane.to_plane(np.array(cfg.camera.xyz)))


def test_the_table_lookup_is_the_terminal_values_lookup():
    vlay, _, arrival = _two_goal_tree()
    mean, cov = np.array([0.1, 1.0, 0.4]), np.diag([0.04, 0.01, 0.003])
    table, _, t0, step = vl.value_table(vlay, mean, cov)
    got = vl.table_lookup(vlay, table, t0, step, arrival)
    assert np.array_equal(got, vl.terminal_values(vlay, mean, cov, arrival).value)
