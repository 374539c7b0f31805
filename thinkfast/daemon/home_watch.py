"""The daemon away from home (at start-up, or after the arm was jogged): hold and say so; with
``go_home``, check the way home against the cell between replies and command it once clear
(:mod:`thinkfast.control.way_home`; docs/CELL.md)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from thinkfast.control.core import ControlCore
from thinkfast.control.way_home import WayHome
from thinkfast.robot.model import Robot

log = logging.getLogger("thinkfast.run")


class HomeWatch:
    """Away from home: an ``away_from_home`` event per place held, and the checked way home.

    Args:
        robot: the robot (its home [rad] (6,) and, for the check, its collision model).
        go_home: check the way home and take it once clear; False: hold where it stands.
        dt: EGM cycle [s] the way home is sampled at.
        new_executor: a fresh executor planning the way home (the daemon's naive one).
        event: ``event(t, kind, detail)``, the daemon's log line and record row.

    Attributes:
        way_home: the check of the way from where the arm stands (None: none begun).
    """

    def __init__(
        self,
        robot: Robot,
        go_home: bool,
        dt: float,
        new_executor: Callable[[], object],
        event: Callable[[float, str, dict], None],
    ):
        self.robot, self.go_home, self.dt = robot, go_home, dt
        self.new_executor, self.event = new_executor, event
        self.way_home: WayHome | None = None
        self._checker = None  # collision model of the cell, built for the first way home
        self._logged: tuple | None = None  # the place last reported

    def held(self, control: ControlCore) -> bool:
        """Held away from home for good (``--hold-away``, or the way home is blocked): not
        idle, which the contract defines as at home and ready."""
        if not control.away:
            return False
        return not self.go_home or (self.way_home is not None and self.way_home.result is not None)

    def service(
        self,
        control: ControlCore,
        time_left: Callable[[float], float],
        plan_time: Callable[[float], float],
    ) -> None:
        """One step between replies: ``time_left(now)`` [s] of work fit before the next reply;
        ``plan_time(now)``: when a plan made now takes effect [s]."""
        if not control.away or control.standby or control.last is None:
            return
        q0 = np.array(control.sup.q)
        key = tuple(np.round(q0, 4))
        if self._logged != key:
            self._logged = key
            far = np.abs(q0 - self.robot.home)
            joint = int(np.argmax(far))
            self.event(
                control.clock.t,
                "away_from_home",
                {
                    "q": np.round(q0, 4).tolist(),
                    "furthest": f"joint_{joint + 1} {far[joint]:.3f} rad",
                    "action": "checking the way home" if self.go_home else "holding here "
                    "(balls ignored): jog the arm home, or restart without --hold-away",
                },
            )  # fmt: skip
            self.way_home = None
        if not self.go_home:
            return
        if self.way_home is None:
            if self._checker is None:
                from thinkfast.robot.collision import CollisionChecker

                self._checker = CollisionChecker(self.robot)
            self.way_home = WayHome(self.new_executor, self._checker, q0, self.dt)
        if self.way_home.result is not None:
            return
        budget = min(0.002, time_left(time.time()) - 0.0005)
        if budget <= 0.0:
            return
        r = self.way_home.step(time.perf_counter() + budget)
        if r is None:
            return
        detail = {"clear": r.clear, "duration": round(r.duration, 3), "samples": r.samples}
        if r.clear:
            control.go_home(plan_time(time.time()))
            control.invalidate()
            self.event(control.clock.t, "way_home", detail)
        else:
            log.error("the way home collides (%s): holding; jog the arm home", r.detail)
            self.event(control.clock.t, "way_home", {**detail, "collision": r.detail})
