"""The flight watch (thinkfast/estimate/retract.py): never retracts a ball in flight, retracts a
ball that stopped in the hand soon after it stopped, on the simulated camera's detections."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.estimate.launch import FlightFit
from thinkfast.estimate.retract import FlightWatch, RetractConfig, not_flying
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.throws import ThrowConfig, plane_crossing, sample_throws

CFG = RunConfig()


def _watch(**retract) -> FlightWatch:
    rc = dataclasses.replace(CFG.retract, **retract)
    return FlightWatch(rc, CFG.launch, CFG.filter, CFG.camera.xyz)


def _in_base(d) -> np.ndarray:
    return CFG.camera.rotation() @ np.asarray(d.position_camera) + CFG.camera.translation()


def _fit(vx: float, sd: float) -> FlightFit:
    cov = np.eye(6) * 1e-4
    cov[3, 3] = sd * sd
    return FlightFit(0.0, np.array([7.0, 0.0, 1.5, vx, 0.0, 0.0]), cov, 1.0, np.zeros(3), 6)


def test_a_ball_is_not_flying_when_its_approach_speed_is_below_the_bound_with_confidence():
    rc = RetractConfig(max_speed=5.0, sigmas=2.0)
    assert not_flying(_fit(0.0, 1.0), rc)  # at rest, well known
    assert not_flying(_fit(+2.0, 1.0), rc)  # moving away from the plane
    assert not not_flying(_fit(-4.0, 1.0), rc)  # 4 + 2 sd = 6: might be a slow flight
    assert not not_flying(_fit(0.0, 3.0), rc)  # at rest, but too uncertain to tell
    assert not not_flying(_fit(-9.0, 0.5), rc)  # a throw


@pytest.mark.parametrize("outliers", [None, 0.04], ids=["camera", "twice-the-outliers"])
def test_no_ball_in_flight_is_ever_retracted(outliers):
    """Every detection of 80 throws (half wind-ups) from 20 ms after the release to the plane,
    the confirmation's earliest: not one retraction. With gross depth outliers twice as often
    as the camera model (purely along the viewing ray, where they fake speed best) too: with
    fits of 4 to 7 detections allowed to count (``min_points``), throw s21-23's first two
    flight detections, 1.3 and 0.6 m nearer than the ball, made a slow ball of two fits."""
    cam = CameraModelConfig()
    if outliers is not None:
        cam = dataclasses.replace(cam, outlier_prob=outliers, outlier_lateral=0.0)
    fits = 0
    for i, th in enumerate(sample_throws(ThrowConfig(), 80, seed=21)):
        t_cross = plane_crossing(th).t
        dets = observe(th, cam, CFG.camera, np.random.default_rng(7000 + i), 0.0)
        watch = _watch()
        for d in sorted(dets, key=lambda d: d.capture_stamp):
            if 0.02 <= d.capture_stamp < t_cross:
                assert not watch.add(d.capture_stamp, _in_base(d)), (th.id, d.capture_stamp)
        fits += watch.fits.fits
    assert fits > 80 * 10  # the watch did fit (a window of 4 or more) all along the flights


def test_a_feint_is_retracted_soon_after_its_ball_stops():
    """40 feints, watched from 20 ms before their ball stops (the launch detector confirmed
    the ones that fooled it around the stop): each is retracted within half a second of the
    stop (the arm then still has 1.5 s to be home), and never while the ball still swings."""
    after = []
    for j, th in enumerate(sample_throws(ThrowConfig(), 0, seed=21, feints=40)):
        dets = observe(th, CameraModelConfig(), CFG.camera, np.random.default_rng(j), 0.0)
        watch = _watch()
        at = None
        for d in sorted(dets, key=lambda d: d.capture_stamp):
            if d.capture_stamp >= -0.02 and watch.add(d.capture_stamp, _in_base(d)):
                at = d.capture_stamp
                break
        assert at is not None, th.id
        after.append(at)
    assert min(after) > 0.0 and max(after) <= 0.5, np.round(after, 3)


def test_detections_out_of_order_from_several_cameras_are_put_in_time_order():
    watch = _watch()
    side, fcfg = np.array([4.8, 4.0, 1.2]), CFG.filter
    p = np.array([7.0, 0.0, 1.5])
    for k in range(6):
        assert not watch.add(10.0 + 0.02 * k, p, side, fcfg)
    assert not watch.add(10.01, p, side, fcfg)  # another camera's, older: fitted in its place
    assert [round(x[0], 3) for x in watch.fits.points][:3] == [10.0, 10.01, 10.02]
    watch.reset()
    assert watch.slow == 0 and not watch.fits.points
