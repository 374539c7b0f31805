"""The planner interface: what a planner of the executor is given and what it returns.

A planner decides where the arm goes once a throw is confirmed. Built once per executor from the
runtime tree, the robot, the runtime config and the executor's segment timeline (which it
reads), it is clock-free: every call carries the time on the controller's clock [s].
:meth:`Planner.decide` takes a :class:`Belief` at every belief from the confirmation on and
returns an :class:`Act` (leave home now, the value of its choice, the :class:`Follow` to take:
a segment from the commanded state, so plans stay continuous), which the executor applies
(:func:`follow`); :meth:`Planner.advance` returns the next :class:`Follow` along plans made of
pieces (tree edges). Class attributes say what else it needs from the executor (``gate``,
``hedges``, ``full_limits``, ``slow``). The table of calls: docs/ARCHITECTURE.md, "Planners";
the registry (:mod:`thinkfast.control.planners.registry`) names the planners.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.foresight import foresight
from thinkfast.control.segments import EDGE, STEER, Segment
from thinkfast.control.timeline import Timeline
from thinkfast.decide import lookahead as lk
from thinkfast.decide.tree_view import Decision, RuntimeTree
from thinkfast.estimate.crossing import Crossing
from thinkfast.robot.model import Robot

CONFIRM, FIRST = "confirm", "first"  # throw gates (thinkfast/control/gate.py)


@dataclass
class EpisodeLog:
    """What the current throw did (for status, records and the judge); times [s]."""

    t_confirmed: float = math.nan
    t_start: float = math.nan
    t_cross: float = math.nan
    path: list[int] = field(default_factory=list)  # tree nodes reached
    terminal: int = -1
    chosen_value: float = math.nan
    decisions: int = 0
    t_hedge: float = math.nan  # when the first hedge of the throw began (nan: none)
    hedges: int = 0  # hedges begun in this episode
    hedge_end: str = ""  # why its last hedge ended, once the episode ended ("": none)
    end: str = ""  # why the throw's motion ended (Executor.throw_end; "": not yet)


class Belief(NamedTuple):
    """What a planner is given at every belief from the confirmation on.

    Attributes:
        t_now: when a plan made now starts (the next controller cycle) [s].
        stamp: capture time of the detection behind the belief [s].
        crossing: the belief's crossing of the plane (``ok`` False: none predicted).
        mean: belief mean (6,): ball position [m] and velocity [m/s] in ``base``.
        executing: the arm has left home in this throw.
        t_start: when it left [s] (nan while it has not).
        cov: belief covariance (6, 6) (None: not given; the look-ahead then values by QMDP).
        r: the filter's adapted measurement noise [m^2] (3, 3), or None.
    """

    t_now: float
    stamp: float
    crossing: Crossing
    mean: np.ndarray
    executing: bool
    t_start: float
    cov: np.ndarray | None = None
    r: np.ndarray | None = None


class Act(NamedTuple):
    """What a planner returns from a belief.

    Attributes:
        leave: the arm leaves home now (the executor starts the episode's motion at ``t_now``).
        value: the value of the choice made (None: none to record).
        follow: the motion to follow (None: the motion in progress goes on).
    """

    leave: bool = False
    value: float | None = None
    follow: Follow | None = None


STAY = Act()
KEEP = "keep"  # a Follow's pending edge: the one queued stays


class Follow(NamedTuple):
    """A planner's decision of motion, applied by the executor (:func:`follow`).

    Attributes:
        segment: the joint 1-3 segment to follow from now on (None: the one in progress stays).
        pending: the compiled child edge queued for the end of the segment, ``(child,
            t_switch [s])``, None for none, :data:`KEEP` to leave it as it is.
        node: the tree node the motion leaves from (None: unchanged).
        path: tree nodes the motion enters with it (the episode's path).
    """

    segment: Segment | None = None
    pending: tuple[int, float] | str | None = KEEP
    node: int | None = None
    path: tuple[int, ...] = ()


def follow(timeline: Timeline, ep: EpisodeLog, f: Follow | None) -> None:
    """Apply the planner's decision ``f`` (None: nothing) to the executor's timeline and the
    episode's path."""
    if f is None:
        return
    if f.pending != KEEP:
        timeline.pending = f.pending
    if f.segment is not None:
        timeline.segment = f.segment
    if f.node is not None:
        timeline.node = f.node
    ep.path.extend(f.path)


class Planner:
    """Base of the executor's planners (module doc).

    Args:
        tree: the runtime tree.
        robot: the robot (limits, home).
        cfg: runtime configuration (with the registry entry's settings applied).
        timeline: the executor's segment timeline, the planner's output.
    """

    gate: ClassVar[str] = CONFIRM
    hedges: ClassVar[bool] = False
    full_limits: ClassVar[bool] = False
    slow: ClassVar[bool] = False  # a decision may outlast an EGM cycle (online: --reply-process)

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, timeline: Timeline):
        self.tree, self.robot, self.cfg, self.timeline = tree, robot, cfg, timeline
        self.n_arm = robot.n_arm  # the timeline's joints, q[:n_arm]
        self.lag = cfg.execution.controller_lag
        self.decision: Decision | None = None  # the at-rest backup of the last belief
        self.foresight = foresight(tree, cfg)  # the look-ahead's camera model (None: QMDP)
        self.realtime = False  # the daemon's: a decision late on the wall clock may be dropped

    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        """Plan on the belief ``b`` (module doc); returns what the executor records."""
        raise NotImplementedError

    def advance(self, t: float, ep: EpisodeLog) -> Follow | None:
        """Every tick while the arm is out, before the timeline is sampled at ``t`` [s]: the
        motion to follow on from there (None: the one in progress goes on)."""
        return None

    def resume_edge(self, q: np.ndarray) -> tuple[str, np.ndarray, int]:
        """(kind, joint 1-3 target [rad] (n_arm,), ref) the compiled tree edge in progress
        becomes when planned again from the joints ``q`` (n_joints,): a move to the most
        probable goal of the last decision (none: a stop at ``q``)."""
        d, n = self.decision, self.n_arm
        goal = -1 if d is None or d.backup is None else int(d.backup.best_goal)
        return STEER, self.tree.goal_q[goal, :n] if goal >= 0 else q[:n], goal

    def value(self) -> tuple[float, int] | None:
        """(value, goal) of the last decision: the at-rest backup at the timeline's node and its
        most probable goal; None before any."""
        d = self.decision
        if d is None or d.backup is None:
            return None
        return float(d.backup.value[self.timeline.node]), int(d.backup.best_goal)

    def reset(self) -> None:
        """The throw was dropped: forget its decisions."""
        self.decision = None

    def backup(self, b: Belief) -> Decision:
        """The at-rest backup of the tree under ``b`` (from where the arm left home, or from
        now while it has not), kept as :attr:`decision`."""
        t_start = b.t_start if b.executing else b.t_now
        node, ahead = 0, None
        if self.foresight is not None and b.cov is not None and b.crossing.ok:
            node = self.choice_node(b)
            if node >= 0:
                h = self.tree.commit_horizon(node, t_start, b.t_now)
                ahead = lk.ahead(
                    b.mean, b.cov, b.crossing.cov, h, self.foresight, self.tree.plane_x,
                    self.cfg.value.lookahead_min_std, b.r,
                )  # fmt: skip
        self.decision = self.tree.decide(
            b.crossing, b.stamp, t_start, self.lag, ahead, max(node, 0)
        )
        return self.decision

    def choice_node(self, b: Belief) -> int:
        """The tree node where the arm chooses its next edge: home (0) before it leaves, the
        end of the compiled edge in progress, -1 off the tree (a move to a goal)."""
        if not b.executing:
            return 0
        seg = self.timeline.segment
        return int(seg.ref) if seg.kind == EDGE else -1

    def rush(self, b: Belief) -> Act:
        """To the goal nearest the most likely crossing point, from the commanded state (kept
        when it already goes there); leaves home. Nothing without a crossing."""
        c = b.crossing
        if not c.ok:
            return STAY
        goal = self.tree.nearest_goal(c.mean[:2])
        seg = self.timeline.segment
        if seg.kind == STEER and seg.ref == goal:
            return Act(leave=True)
        return Act(leave=True, follow=self.steer(goal, b.t_now))

    def steer(self, goal: int, t: float) -> Follow | None:
        """A move to rest at ``goal`` from the commanded state at ``t`` [s]; None when Ruckig
        fails (the motion in progress goes on)."""
        seg = self.timeline.steer_segment(self.tree.goal_q[goal, : self.n_arm], goal, t)
        return None if seg is None else Follow(seg, None)
