"""The hedge stage of a throw episode, before the launch is confirmed (:mod:`.hedge`).

For a planner that hedges (the tree planner) with ``[hedge] mode`` not ``none`` and the launch
detector on: once the early belief makes a launch likely, the arm may start on a move kept
within ``[hedge] bound`` of home (``stage`` = ``hedge``); each new detection re-plans. A hedge
given up (``hedge_end``: ``no_launch``, ``timeout``, ``silence``) returns home while still
tracking (the episode ends only once the arm is home; after a ``timeout`` no hedge starts again
in that episode); at the confirmation the planner takes over from the commanded state
(``stage`` = ``commit``; the throw is under way when the arm is off home). Clock-free: every
time is an argument [s].
"""

from __future__ import annotations

import math

import numpy as np

from thinkfast.control.config import RunConfig, early_config
from thinkfast.control.foresight import foresight
from thinkfast.control.hedge import COMMIT, HEDGE, Hedger
from thinkfast.control.planners.base import EpisodeLog, Planner
from thinkfast.control.timeline import Timeline
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.robot.model import Robot


class HedgeStage:
    """The hedge stage of one executor (module doc).

    Args:
        hedger: targets and checked moves.
        timeline: the executor's segment timeline (the stage moves it).
        timeout: ``[hedge] timeout`` [s].

    Attributes:
        stage: ``""``, ``hedge`` or ``commit``: the stage of the current throw.
        hedge_end: why the last hedge ended: confirmed, no_launch, timeout, silence.
        hedges: hedges begun since the start.
    """

    def __init__(self, hedger: Hedger, timeline: Timeline, timeout: float):
        self.hedger, self.timeline, self.timeout = hedger, timeline, timeout
        self.stage = ""
        self.hedge_end = ""
        self.hedge_t0 = -np.inf  # when the hedge in progress began
        self.hedges = 0
        self.off = False  # no more hedges in this episode (one timed out)
        self.home_after = False  # a given-up hedge goes home once its move ends

    def on_belief(self, t_now: float, stamp: float, points: list, ep: EpisodeLog) -> None:
        """Before the confirmation, at every belief: start, re-plan or end a hedge on the early
        belief of the launch detector's detections ``points`` (the newest captured at
        ``stamp``)."""
        if self.off:
            return
        fit, c = self.hedger.belief(points)
        if fit is None:
            if self.stage == HEDGE:
                self.end(t_now, "no_launch")
            return
        tl = self.timeline
        target = self.hedger.target(c, stamp, t_now, fit)
        seg = self.hedger.plan(tl.state(t_now), target, t_now)
        if seg is None:
            return  # the move in progress stays (it is within the bound)
        self.home_after = False
        if self.stage != HEDGE:
            self.stage, self.hedge_t0 = HEDGE, t_now
            self.hedges += 1
            ep.hedges += 1
            if math.isnan(ep.t_hedge):
                ep.t_hedge = t_now
        tl.segment = seg
        tl.pending = None

    def tick(self, t: float, silent: bool) -> None:
        """Before the confirmation, every tick: end a hedge at its time limit or when the ball
        is lost (``silent``); home from where a given-up hedge stopped."""
        if self.stage == HEDGE and t - self.hedge_t0 > self.timeout:
            self.end(t, "timeout")
            self.off = True
        elif self.stage == HEDGE and silent:
            self.end(t, "silence")
        if self.home_after and t >= self.timeline.segment.t_end:
            self.home_after = False
            self.timeline.start_return(t)

    def commit(self, t_now: float) -> bool:
        """The launch is confirmed: the planner takes over from wherever the arm is. True when
        the arm has left home (the throw's motion is under way)."""
        out = self.stage == HEDGE or not self.timeline.at_home(t_now)
        if self.stage == HEDGE:
            self.hedge_end = "confirmed"
        self.stage = COMMIT
        self.home_after = False
        return out

    def end(self, t: float, why: str) -> None:
        """Give the hedge up, still tracking the ball: home (:meth:`Timeline.home_move`) when
        that way stays within the bound (a faster hedge brakes later with the return limits);
        else on to the hedge's own target (checked) and home from there."""
        self.stage, self.hedge_end = "", why
        tl = self.timeline
        state = tl.state(t)
        tl.pending = None
        seg = tl.home_move(state, t, self.hedger.within)
        if seg is not None:
            tl.segment = seg
            return
        self.home_after = True  # the segment in progress stops within the bound

    def drop(self) -> None:
        """The episode ended: the next one may hedge again."""
        self.stage = ""
        self.off = False
        self.home_after = False


def hedge_stage(
    planner: Planner, tree: RuntimeTree, robot: Robot, cfg: RunConfig, timeline: Timeline
) -> HedgeStage | None:
    """The hedge stage of an executor running ``planner``; None when it does not hedge, with
    ``[hedge] mode = none`` or without the launch detector."""
    if not planner.hedges or cfg.hedge.mode == "none" or not cfg.launch.enabled:
        return None
    h, lag = cfg.hedge, cfg.execution.controller_lag
    hedger = Hedger(
        tree, robot, timeline.steer, h, early_config(cfg), cfg.filter.gravity, lag,
        foresight(tree, cfg), cfg.value.lookahead_min_std,
    )  # fmt: skip
    return HedgeStage(hedger, timeline, h.timeout)
