"""ZED 2i model: noise statistics, outliers, dropouts, timing, visibility, payloads, modes."""

import dataclasses
import json
import math

import numpy as np
import pytest

from thinkfast.contract.camera_mode import CameraSetup
from thinkfast.contract.detection import Detection, parse_detection
from thinkfast.contract.frames import CameraExtrinsic, to_base
from thinkfast.sim.camera import (
    CameraModelConfig,
    blur_pixels,
    depth_sigma,
    detection_payload,
    dropout_mask,
    gross_error,
    in_view,
    measure,
    mode_model,
    noise_covariance,
    observe,
    outlier_probability,
)
from thinkfast.sim.thrower import STILL_MIX
from thinkfast.sim.throws import ThrowConfig, make_throw, sample_throws

CAM = CameraModelConfig()
CLEAN = dataclasses.replace(CAM, outlier_prob=0.0, blur_outlier_prob=0.0)
EXT = CameraExtrinsic()
T0 = 1_763_800_000.0  # a wall-clock release time


@pytest.fixture(scope="module")
def throws():
    return sample_throws(ThrowConfig(), 50, seed=5)


def _points(p, n=4000):
    return np.tile(np.asarray(p, float), (n, 1))


@pytest.mark.parametrize("depth", [2.0, 4.0, 8.0])
def test_depth_noise_std_is_z2_sigma_d_over_fB(depth):
    p = _points([depth, 0.0, 0.0])
    err = measure(p, 0.2, CAM, np.random.default_rng(1)) - p
    expect = depth**2 * 0.2 / (CAM.focal_px * CAM.baseline)  # 5.0 cm at 4 m
    assert err[:, 0].std() == pytest.approx(expect, rel=0.1)
    assert abs(err[:, 0].mean()) < 4 * expect / math.sqrt(len(p))


def test_lateral_noise_std_is_z_sigma_px_over_f():
    p = _points([4.0, 0.0, 0.0])
    err = measure(p, 0.2, CAM, np.random.default_rng(2)) - p
    expect = 4.0 * CAM.pixel_sigma / CAM.focal_px  # 3.8 mm
    assert err[:, 1].std() == pytest.approx(expect, rel=0.1)
    assert err[:, 2].std() == pytest.approx(expect, rel=0.1)


def test_off_axis_noise_lies_along_the_viewing_ray_as_the_covariance_says():
    p = _points([3.0, 1.5, -0.8], n=20000)
    err = measure(p, 0.25, CAM, np.random.default_rng(3)) - p
    model = noise_covariance(p[:1], 0.25, CAM)[0]
    np.testing.assert_allclose(np.cov(err.T), model, rtol=0.05, atol=0.05 * model[0, 0])


def test_observed_errors_match_the_reported_covariance_over_many_throws(throws):
    rng = np.random.default_rng(4)
    d2 = []
    R, c = EXT.rotation(), EXT.translation()
    for th in throws:
        for sd in observe(th, CLEAN, EXT, rng, T0):
            err = sd.position_camera - R.T @ (sd.true_position_base - c)
            d2.append(err @ np.linalg.solve(sd.covariance, err))
    assert len(d2) >= 2000
    assert np.mean(d2) == pytest.approx(3.0, rel=0.05)  # chi-square with 3 degrees of freedom


def test_noise_level_is_drawn_per_throw_inside_the_configured_range(throws):
    rng = np.random.default_rng(5)
    levels = []
    for th in throws[:20]:
        sd = observe(th, CLEAN, EXT, rng, T0)[0]
        depth = sd.true_position_base[0] - EXT.xyz[0]
        s_z = math.sqrt(sd.covariance[0, 0])
        levels.append(s_z * CAM.focal_px * CAM.baseline / depth**2)
    assert min(levels) >= CAM.disparity_sigma[0] - 1e-6
    assert max(levels) <= CAM.disparity_sigma[1] + 1e-6
    assert max(levels) - min(levels) > 0.05


def test_outlier_rate_of_a_still_ball_is_the_configured_rate_with_large_depth_errors():
    cfg = ThrowConfig()
    held = make_throw(cfg, np.array([7.5, 0.3, 1.4]), (0.0, 1.0), 0.6, t_release=100.0)
    cam = dataclasses.replace(CAM, dropout_rate=0.0)
    dets = observe(held, cam, EXT, np.random.default_rng(6), T0, until=-1.0)
    n = len(dets)
    assert n >= 4900
    out = [d for d in dets if d.is_outlier]
    sd = math.sqrt(CAM.outlier_prob * (1 - CAM.outlier_prob) / n)
    assert abs(len(out) / n - CAM.outlier_prob) < 4 * sd
    R, c = EXT.rotation(), EXT.translation()
    for d in out:
        err = d.position_camera - R.T @ (d.true_position_base - c)
        assert CAM.outlier_error[0] - 0.01 <= abs(err[0]) <= CAM.outlier_error[1] + 0.01
        assert abs(err[0]) > np.linalg.norm(err[1:])  # mostly along depth


def test_gross_errors_never_come_closer_than_the_minimum_range():
    p = _points([0.5, 0.0, 0.0], n=1000)
    assert (gross_error(p, CAM, np.random.default_rng(7))[:, 0] >= CAM.min_range - 1e-12).all()


def test_motion_blur_makes_outliers_more_likely_near_the_camera():
    v = np.array([[-15.0, 0.5, 1.0]] * 2)
    p = np.array([[1.0, 0.2, 0.3], [6.0, 0.2, 0.3]])
    blur = blur_pixels(p, v, CAM)
    assert blur[0] > 5 * blur[1]
    prob = outlier_probability(blur, CAM)
    assert prob[1] >= CAM.outlier_prob and prob[0] > prob[1]
    assert prob.max() <= CAM.outlier_prob + CAM.blur_outlier_prob


def test_dropout_rate_and_mean_burst_length_are_as_configured():
    mask = dropout_mask(60000, CAM, np.random.default_rng(8))
    assert mask.mean() == pytest.approx(CAM.dropout_rate, abs=0.006)
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    bursts = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    assert bursts.mean() == pytest.approx(CAM.dropout_burst, rel=0.1)


def test_latency_is_inside_its_range_and_delivery_follows_capture_order(throws):
    rng = np.random.default_rng(9)
    for th in throws[:10]:
        dets = observe(th, CAM, EXT, rng, T0)
        lat = np.array([d.delivery_time - d.capture_stamp for d in dets])
        assert (lat >= CAM.latency[0] - 1e-6).all() and (lat <= CAM.latency[1] + 1e-6).all()
        assert (np.diff([d.delivery_time for d in dets]) >= 0).all()


def test_stamps_increase_strictly_on_the_20ms_frame_grid(throws):
    no_drop = dataclasses.replace(CAM, dropout_rate=0.0)
    th = throws[0]
    dets = [d for d in observe(th, no_drop, EXT, np.random.default_rng(10), T0) if d.seq < 30]
    np.testing.assert_allclose(np.diff([d.capture_stamp for d in dets]), 0.02, atol=1e-6)
    dets = observe(th, CAM, EXT, np.random.default_rng(11), T0)
    steps = np.diff([d.capture_stamp for d in dets]) / 0.02
    assert (steps > 0.5).all()
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-4)
    assert (np.diff([d.seq for d in dets]) == np.round(steps)).all()


def test_ball_is_visible_in_the_hand_before_release():
    """Still holds: the ball is seen where it will be released (a wind-up moves it first)."""
    cfg = ThrowConfig()
    still = dataclasses.replace(cfg, thrower=dataclasses.replace(cfg.thrower, mix=STILL_MIX))
    rng = np.random.default_rng(12)
    for th in sample_throws(still, 5, seed=5):
        assert th.kind == "still"
        dets = observe(th, CAM, EXT, rng, T0)
        before = [d for d in dets if d.capture_stamp < T0]
        assert len(before) >= 0.7 * th.t_release * CAM.rate
        assert before[0].capture_stamp <= T0 - th.t_release + 0.02 + 1e-6
        for d in before:
            assert np.linalg.norm(d.true_position_base - th.p_release) < 0.01


def test_observation_ends_just_after_the_plane_crossing(throws):
    th = throws[1]
    dets = observe(th, CAM, EXT, np.random.default_rng(13), T0)
    assert dets[-1].capture_stamp <= T0 + th.flight_time + CAM.after_crossing + 1e-6


def test_ball_outside_the_image_or_the_range_is_not_seen():
    half_v = math.atan(CAM.image_size[1] / 2 / CAM.focal_px)  # 34 deg
    pts = np.array([
        [5.0, 0.0, 0.0],  # straight ahead
        [5.0, 0.0, 5.0 * math.tan(half_v) * 0.98],  # just inside the top edge
        [5.0, 0.0, 5.0 * math.tan(half_v) * 1.02],  # just outside
        [1.0, 1.3, 0.0],  # 52 deg left, outside 50 deg
        [-2.0, 0.0, 0.0],  # behind
        [0.2, 0.0, 0.0],  # too close
        [21.0, 0.0, 0.0],  # too far
    ])  # fmt: skip
    assert in_view(pts, CAM).tolist() == [True, True, False, False, False, False, False]


def test_observation_is_deterministic_given_the_rng_seed(throws):
    a = observe(throws[2], CAM, EXT, np.random.default_rng(14), T0)
    b = observe(throws[2], CAM, EXT, np.random.default_rng(14), T0)
    assert [d.seq for d in a] == [d.seq for d in b]
    np.testing.assert_array_equal([d.position_camera for d in a], [d.position_camera for d in b])


def test_payloads_follow_the_contract_and_come_back_to_base_within_noise(throws):
    ext = CameraExtrinsic(xyz=(0.5, -0.2, 0.4), rpy=(0.02, -0.08, 0.1))
    R, c = ext.rotation(), ext.translation()
    n_in = 0
    for th in throws[:5]:
        for sd in observe(th, CAM, ext, np.random.default_rng(15), T0):
            obj = json.loads(detection_payload(sd))
            assert set(obj) == {"stamp", "position", "frame", "confidence", "seq"}
            det = parse_detection(detection_payload(sd, with_covariance=True))
            assert isinstance(det, Detection), det
            assert det.frame == "camera" and det.stamp == sd.capture_stamp and det.seq == sd.seq
            base = to_base(det, R, c)
            if not sd.is_outlier:
                n_in += 1
                err = base.position - sd.true_position_base
                assert err @ np.linalg.solve(base.covariance, err) < 25.0  # 5 sigma
    assert n_in > 100


def test_depth_sigma_matches_the_published_figures():
    # docs/FACTS.md: 0.1-0.25 px -> 2.5-6 cm at 4 m, 10-25 cm at 8 m
    assert depth_sigma(4.0, 0.1, CAM) == pytest.approx(0.025, abs=0.001)
    assert depth_sigma(8.0, 0.25, CAM) == pytest.approx(0.25, abs=0.01)


VGA = CameraSetup(mode="VGA", fps=100.0)


def test_hd720_at_50_fps_is_the_default_model_and_other_modes_keep_the_pixel_noise():
    assert mode_model(CameraSetup()) == CAM
    vga = mode_model(VGA)
    assert (vga.rate, vga.focal_px, vga.image_size) == (100.0, 265.0, (672, 376))
    assert (vga.disparity_sigma, vga.pixel_sigma) == (CAM.disparity_sigma, CAM.pixel_sigma)
    assert mode_model(CameraSetup(fps=60.0)).focal_px == CAM.focal_px


@pytest.mark.parametrize("depth", [4.0, 7.0])
def test_vga_noise_in_metres_is_hd720s_times_the_focal_ratio(depth):
    """Same disparity and pixel noise, half the focal length: depth noise ``z^2 s / (f B)`` and
    lateral noise ``z s_px / f`` both about double (4 m, 0.2 px: 10 cm instead of 5 cm)."""
    p = _points([depth, 0.0, 0.0], n=20000)
    vga = mode_model(VGA)
    err_vga = measure(p, 0.2, vga, np.random.default_rng(21)) - p
    err_hd = measure(p, 0.2, CAM, np.random.default_rng(22)) - p
    assert err_vga[:, 0].std() == pytest.approx(depth**2 * 0.2 / (265.0 * 0.12), rel=0.05)
    assert err_vga[:, 1].std() == pytest.approx(depth * 0.5 / 265.0, rel=0.05)
    ratio = err_vga.std(axis=0) / err_hd.std(axis=0)
    np.testing.assert_allclose(ratio, 532.0 / 265.0, rtol=0.05)


@pytest.mark.parametrize("setup, interval", [(VGA, 0.01), (CameraSetup(fps=60.0), 1.0 / 60.0)])
def test_frames_come_every_frame_interval_of_the_mode(throws, setup, interval):
    model = dataclasses.replace(mode_model(setup), dropout_rate=0.0, detect_probs=(1.0,) * 4)
    th = throws[0]
    dets = observe(th, model, EXT, np.random.default_rng(23), T0)
    held = [d for d in dets if d.capture_stamp < T0 - 0.05]  # in the hand: always in view
    assert len(held) >= 0.9 * (th.t_release - 0.05) / interval
    np.testing.assert_allclose(np.diff([d.capture_stamp for d in held]), interval, atol=1e-6)


def test_vga_misses_far_balls_at_the_measured_rate_and_keeps_every_other_draw():
    """A held ball 7.0 m deep is found in 91 % of VGA frames (96 % at 6.5 m, 87 % at 7.5 m),
    one 5 m deep in all; the frames it keeps are exactly those drawn without the misses."""
    cfg = ThrowConfig()
    vga = dataclasses.replace(mode_model(VGA), dropout_rate=0.0)
    found = dataclasses.replace(vga, detect_probs=(1.0, 1.0, 1.0, 1.0))
    for x, rate in ((EXT.xyz[0] + 7.0, 0.96 - 0.09 * 0.5), (EXT.xyz[0] + 5.0, 1.0)):
        held = make_throw(cfg, np.array([x, 0.0, EXT.xyz[2]]), (0.0, 1.0), 0.6, t_release=50.0)
        dets = observe(held, vga, EXT, np.random.default_rng(24), T0, until=-1.0)
        every = observe(held, found, EXT, np.random.default_rng(24), T0, until=-1.0)
        n = len(every)
        assert n >= 4900
        assert abs(len(dets) / n - rate) <= 4 * math.sqrt(rate * (1 - rate) / n) + 1e-12
        kept = {d.seq: d for d in every}
        for d in dets:
            np.testing.assert_array_equal(d.position_camera, kept[d.seq].position_camera)
