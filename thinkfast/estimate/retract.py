"""Retraction: is the ball of a confirmed throw still in free flight towards the plane?

The launch detector (:mod:`thinkfast.estimate.launch`) confirms a throw from a few detections,
and a feint's forward swing can pass its tests: the arm leaves home and the ball stops in the
hand, while the filter's predicted crossing keeps receding. From the confirmation on,
:class:`FlightWatch` fits a free flight to the newest detections (the launch detector's
weighted, outlier-robust fit) and the throw is *retracted* once ``confirm`` fits in a row
explain their detections and show the ball approaching the plane slower than ``max_speed``
(m/s) with confidence. Pure logic; times are arguments [s].

The test, why a thrown ball never passes it and why the filter's velocity is not used:
docs/DESIGN.md, "Retraction".
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from thinkfast.config import spec
from thinkfast.estimate.filter import FilterConfig
from thinkfast.estimate.launch import FlightFit, LaunchConfig, LaunchDetector


@dataclasses.dataclass(frozen=True)
class RetractConfig:
    """Retracting a confirmed throw whose ball is not in flight (``[retract]``; module doc)."""

    enabled: bool = spec(
        True,
        doc="retract a confirmed throw (the arm goes home) once its ball is seen not to fly "
        "towards the plane (a feint the launch detector confirmed)",
    )
    window: int = spec(
        10, lo=4, hi=12, doc="detections per free-flight fit (the newest since the confirmation)"
    )
    min_points: int = spec(
        8,
        lo=4,
        hi=12,
        doc="detections a fit must use to count (fewer: two depth outliers among them can fake "
        "a slow ball)",
    )
    max_span: float = spec(
        0.25,
        unit="s",
        lo=0.0,
        lo_open=True,
        doc="longest time a fit may cover (the depth noise of a ball 7 m away needs a few "
        "tenths of a second to bound its speed)",
    )
    max_speed: float = spec(
        5.0,
        unit="m/s",
        lo=0.0,
        lo_open=True,
        doc="a ball approaching the plane slower than this with confidence is not a throw's "
        "(throws leave the hand at 8.5 m/s or more, docs/FACTS.md; TUNED on simulated throws "
        'and feints, docs/RESULTS.md "Feints, held balls, starts before release")',
    )
    sigmas: float = spec(2.0, unit="sigma", lo=0.0, doc="confidence of the speed test (2: ~98 %)")
    confirm: int = spec(
        2, lo=1, hi=5, doc="consecutive fits showing such a ball that retract the throw"
    )


def not_flying(fit: FlightFit, cfg: RetractConfig) -> bool:
    """The fit's ball approaches the plane (-x) slower than ``max_speed`` at ``sigmas``."""
    speed_hi = -float(fit.mean[3]) + cfg.sigmas * math.sqrt(float(fit.cov[3, 3]))
    return speed_hi < cfg.max_speed


class FlightWatch:
    """Feeds on a confirmed throw's detections; :meth:`add` says when to retract it.

    Args:
        cfg: retraction parameters.
        launch: the launch detector's parameters (noise model, outliers, residual test, span).
        fcfg: filter parameters (stereo noise model, gravity).
        sensor: default camera origin in base [m], shape (3,).
        cameras: how many cameras feed it.

    Attributes:
        slow: consecutive fits that showed a ball not flying towards the plane.
        retractions: throws it retracted since it was made.
    """

    def __init__(
        self, cfg: RetractConfig, launch: LaunchConfig, fcfg: FilterConfig, sensor, cameras=1
    ):
        self.cfg = cfg
        fits = dataclasses.replace(launch, max_span=cfg.max_span)
        self.fits = LaunchDetector(fits, fcfg, sensor, cameras, cfg.window)
        self.slow = 0
        self.retractions = 0

    def reset(self) -> None:
        """Forget the detections (a throw is confirmed, or over)."""
        self.fits.reset()
        self.slow = 0

    def add(self, t: float, z: np.ndarray, sensor=None, fcfg: FilterConfig | None = None) -> bool:
        """A detection stamped ``t`` [s] at ``z`` [m] (base), from ``sensor`` with the noise
        model of ``fcfg`` (None: the default camera); True when the throw is to be retracted
        (``confirm`` fits in a row showed a ball that does not fly towards the plane)."""
        if not self.fits.insert(t, z, sensor, fcfg):
            return False
        fit = self.fits.fit()
        shows = fit is not None and fit.n >= self.cfg.min_points and self.fits.consistent(fit)
        if not (shows and not_flying(fit, self.cfg)):
            self.slow = 0
            return False
        self.slow += 1
        if self.slow < self.cfg.confirm:
            return False
        self.retractions += self.slow == self.cfg.confirm
        return True
