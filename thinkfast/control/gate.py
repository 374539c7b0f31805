"""The throw gate: detections into the ball filter, and when a tracked ball is a throw.

Clock-free (times are arguments [s]). The filter follows the ball (started afresh when the
previous detection is older than ``throw.detection_timeout``); with several cameras
(docs/CAMERAS.md) each one's origin and noise model is used and a camera whose detections
disagree with the reference camera's is kept out. Two gates (the planner names its own,
:mod:`thinkfast.control.planners.base`): ``confirm`` counts the beliefs that predict a throw
(approaching fast enough, crossing soon, near the goal grid) and takes the launch detector's
launches; ``first`` (the paper's baseline) confirms at the first such belief. With ``confirm``
the flight watch (:mod:`thinkfast.estimate.retract`) may make :class:`Fused` say ``retract``.

The two gates in full: docs/DESIGN.md, "The control core", "The throw gate".
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.control.config import RunConfig, default_camera_filter, launch_window
from thinkfast.control.planners.base import CONFIRM, FIRST
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.estimate import filter as kf
from thinkfast.estimate.crossing import Crossing
from thinkfast.estimate.fusion import DEFAULT_CAMERA, CameraCheck, camera_filter
from thinkfast.estimate.launch import LaunchDetector
from thinkfast.estimate.retract import FlightWatch


class Fused(NamedTuple):
    """What became of one detection.

    Attributes:
        ok: it updated the filter (False: refused, or too late for it).
        launched: the launch detector restarted the filter from its fit.
        refusal: ``"inconsistent_camera"`` when its camera's detections are refused.
        retract: the throw under way is to be retracted (module doc).
    """

    ok: bool
    launched: bool = False
    refusal: str | None = None
    retract: bool = False


class ThrowGate:
    """Ball filter, cameras, launch detector and the throw confirmation (module doc).

    Args:
        tree: the runtime tree (crossings, the goal grid).
        cfg: runtime configuration.
        kind: ``confirm`` or ``first`` (module doc).

    Attributes:
        belief: the ball filter's state.
        confirm: the confirmation count.
        settled: updates absorbed since the filter last (re)started (module doc).
        t_last_det: newest detection stamp fused [s].
        check: the cameras' consistency check (None with the default camera alone).
    """

    def __init__(self, tree: RuntimeTree, cfg: RunConfig, kind: str = CONFIRM):
        if kind not in (CONFIRM, FIRST):
            raise ValueError(f"throw gate {kind!r} is not one of {CONFIRM}, {FIRST}")
        self.tree, self.cfg, self.first = tree, cfg, kind == FIRST
        # camera origins where the belief lives: the plane's frame (base without a pose)
        self.sensor = tree.plane.to_plane(np.array(cfg.camera.xyz, dtype=float))
        n_cam = 1 + len(cfg.cameras)
        window = cfg.fusion.launch_window if cfg.cameras else launch_window(cfg)
        own = default_camera_filter(cfg)  # the stereo noise model of [camera]'s mode
        self.launch = LaunchDetector(cfg.launch, own, self.sensor, n_cam, window)
        self.watch = FlightWatch(cfg.retract, cfg.launch, own, self.sensor, n_cam)
        self.sensors: dict[str | None, tuple[np.ndarray, kf.FilterConfig]] = {
            None: (self.sensor, own)
        }
        self.check: CameraCheck | None = None
        self.reference: str | None = None
        if cfg.cameras:
            for c in cfg.cameras:
                origin = tree.plane.to_plane(np.array(c.xyz, dtype=float))
                self.sensors[c.id] = (origin, camera_filter(cfg.filter, c))
            ref = None if cfg.fusion.reference == DEFAULT_CAMERA else cfg.fusion.reference
            self.reference = ref
            origin, fcfg = self.sensors[ref]
            self.check = CameraCheck(cfg.fusion, fcfg, origin, cfg.throw.detection_timeout)
        self.belief = kf.empty(cfg.filter)
        self.confirm = 0
        self.settled = 0
        self.t_last_det = -np.inf

    def fuse(self, stamp: float, p_base: np.ndarray, camera: str | None, armed: bool) -> Fused:
        """Fuse the ball centre ``p_base`` (3,) [m] in ``base`` captured at ``stamp`` by
        ``camera`` (None: the default camera); ``armed``: no throw is under way (the launch
        detector looks for one)."""
        sensor, fcfg = self.sensors[camera]
        if self.check is not None:
            if camera == self.reference:
                self.check.reference(stamp, p_base)
            elif not self.check.admit(camera, stamp, p_base, kf.stereo_r(p_base, sensor, fcfg)):
                bad = self.check.state(camera).inconsistent
                return Fused(False, refusal="inconsistent_camera" if bad else None)
        if stamp - self.t_last_det > self.cfg.throw.detection_timeout:
            self.belief = kf.empty(self.cfg.filter)  # a new ball: start the filter afresh
            self.confirm = 0
            self.launch.reset()
        lag = self.cfg.fusion.max_lag if self.check is not None else 0.0
        self.belief, info = kf.update(self.belief, stamp, p_base, fcfg, sensor, lag)
        if info.status == "late":
            return Fused(False)
        self.t_last_det = max(self.t_last_det, stamp)
        # updates absorbed since the filter last (re)started from two measurements: before 2,
        # one outlier among those two can fake any velocity. Another camera's older detection
        # (fused out of sequence) does not count towards the filter's recovery from a bad
        # start, so it settles the start only when it agrees with it (an inlier on every axis):
        # counted regardless, two of them settled a start from two base-camera outliers and a
        # held ball was confirmed (docs/RESULTS.md, "Feints, held balls")
        restarted = info.status in ("first", "init") or bool(np.any(info.reset))
        past = info.status == kf.STATUS_PAST
        agrees = not past or bool(np.all(info.weight >= 1.0))
        self.settled = 0 if restarted else self.settled + agrees
        cam = (sensor, fcfg) if self.check is not None else ()
        if not armed:  # a throw is under way: is its ball still flying towards the plane?
            watch = self.cfg.retract.enabled and not self.first
            return Fused(True, retract=watch and self.watch.add(stamp, p_base, *cam))
        self.watch.reset()  # it sees the detections after the confirmation only
        if not (self.cfg.launch.enabled and not self.first):
            return Fused(True)
        several = self.check is not None
        fit = self.launch.add(stamp, p_base, *cam, camera=camera)
        if fit is None:
            return Fused(True)
        newest = None if fit.t != stamp or not several else sensor
        self.belief = kf.restart(self.belief, fit.t, fit.mean, fit.cov, fit.z, newest)
        self.settled = max(self.settled, self.cfg.throw.settle_updates)
        return Fused(True, launched=True)

    def crossing(self) -> Crossing:
        """The belief's crossing of the plane (delta method)."""
        return self.tree.crossing(self.belief.mean, self.belief.cov, self.cfg.filter.gravity)

    def confirms(self, c: Crossing, launched: bool, tracking: bool) -> bool:
        """The belief (crossing ``c``; ``launched``: just restarted by the launch detector) is
        one of a confirmed throw: counted while ``tracking`` (module doc); a throw under way
        stays confirmed."""
        if self.first:
            return not tracking or self.approaching(c, sigmas=0.0)
        if not tracking:
            return True
        th = self.cfg.throw
        if self.settled >= th.settle_updates and self.approaching(c):
            self.confirm = th.confirm_updates if launched else self.confirm + 1
        else:  # one outlier frame costs one step, not the whole count
            self.confirm = max(self.confirm - 1, 0)
        return self.confirm >= th.confirm_updates

    @property
    def confirmed(self) -> bool:
        """The count reached ``confirm_updates`` (never with the ``first`` gate)."""
        return self.confirm >= self.cfg.throw.confirm_updates

    def approaching(self, c: Crossing, sigmas: float | None = None) -> bool:
        """The belief predicts a throw: approaching faster than ``min_approach_speed`` at
        ``sigmas`` (default ``approach_sigmas``), crossing within ``max_tau``, near the goals."""
        th = self.cfg.throw
        k = th.approach_sigmas if sigmas is None else sigmas
        speed_lo = -self.belief.mean[3] - k * np.sqrt(self.belief.cov[3, 3])
        if not c.ok or speed_lo < th.min_approach_speed or c.mean[2] > th.max_tau:
            return False
        y, z = c.mean[0], c.mean[1]
        lo, hi = self.tree.goal_yz.min(axis=0), self.tree.goal_yz.max(axis=0)
        m = th.region_margin
        return lo[0] - m <= y <= hi[0] + m and lo[1] - m <= z <= hi[1] + m

    def drop(self) -> None:
        """The throw was dropped: an empty filter, no count, no flight watch (the launch
        detector goes on)."""
        self.belief = kf.empty(self.cfg.filter)
        self.confirm = 0
        self.watch.reset()
