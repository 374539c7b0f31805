"""Every transition of the executor's state machine, one table row each, driven by real calls.

A row starts an :class:`Executor` on the small test tree, brings it into a situation with real
calls (``start_from``, detections, setpoint ticks, ...), then plays a scripted sequence of inputs
and checks what can be seen afterwards: the states it went through (``away`` for the hold away
from home at start-up), the one it ends in and when it entered it, the kind of segment it
commands, the number of finished throws, whether the current throw started moving, how many
detections the filter holds, whether the arm is home.

Inputs are scripted beliefs: detections at 50 Hz of a ball held still, of a throw from about
7.5 m towards the plane (x = 0.8 m) or of a ball that stops being seen, with a small fixed noise
from a seeded generator, delivered ``LATENCY`` after their stamps; between them the executor is
asked for its setpoint every 4 ms, as the EGM cycle does.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import pytest

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import (
    EXECUTING,
    FAULT,
    IDLE,
    RETURNING,
    TRACKING,
    Executor,
)
from thinkfast.control.segments import EDGE, HOLD, RETURN, STEER, TERMINAL
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.tree.file import load_tree

CFG = RunConfig()
NO_LAUNCH = dataclasses.replace(CFG, launch=dataclasses.replace(CFG.launch, enabled=False))
DT = 0.004  # s: one EGM cycle, one setpoint
FRAME = 0.02  # s: 50 Hz detections
LATENCY = 0.02  # s: a detection reaches the executor this long after its capture stamp
NOISE = 0.002  # m: std of the detection noise, every axis
AWAY = "away"  # the hold away from home at start-up (mode idle, ``away`` set)
G = CFG.filter.gravity
LAG = CFG.execution.controller_lag
TH = CFG.throw

# the throw: held in the hand at HAND from t = 0.5 s, released at RELEASE, crossing the plane
# (x = 0.8 m) at AIM (inside the small tree's goal grid: y -0.9..0.9 m, z 0.25..1.6 m)
HAND = (7.5, 0.2, 1.4)
AIM = (0.1, 0.9)
RELEASE = 1.0
FLIGHT = 0.7
CROSS = RELEASE + FLIGHT
END = CROSS + LAG + TH.after_crossing  # the executor ends a throw seen to the plane here
PLANE_X = 0.8


class Ball(NamedTuple):
    """A ball seen from ``t_seen`` to ``t_lost`` [s]: held at ``hand`` until ``release``, then in
    free flight reaching the plane at ``aim`` (y, z) after ``flight`` [s] (no drag)."""

    hand: tuple[float, float, float] = HAND
    aim: tuple[float, float] = AIM
    release: float = RELEASE
    flight: float = FLIGHT
    t_seen: float = 0.5
    t_lost: float = RELEASE + FLIGHT

    def at(self, t: float) -> np.ndarray | None:
        """Ball centre in ``base`` [m] at ``t`` [s]; None when not seen."""
        if not self.t_seen <= t < self.t_lost:
            return None
        p0 = np.array(self.hand, dtype=float)
        s = t - self.release
        if s <= 0.0:
            return p0
        end = np.array([PLANE_X, *self.aim])
        v0 = (end - p0) / self.flight + [0.0, 0.0, 0.5 * G * self.flight]
        return p0 + v0 * s - [0.0, 0.0, 0.5 * G * s * s]


THROW = Ball()
HELD = Ball(release=math.inf, t_lost=math.inf)  # a ball held still, seen for good


class Run:
    """An executor and its script clock; records every change of state with its time."""

    def __init__(self, ex: Executor, seed: int):
        self.ex = ex
        self.t = 0.0
        self.rng = np.random.default_rng(seed)
        self.stamp = 0.0  # next detection stamp [s] (a 50 Hz grid)
        self.q = np.array(ex.robot.home, dtype=float)  # last commanded joints [rad]
        self.log: list[tuple[float, str, str]] = []  # (time [s], state, segment kind)

    def state(self) -> str:
        return AWAY if self.ex.away else str(self.ex.mode)

    def note(self) -> None:
        if not self.log or self.log[-1][1] != self.state():
            self.log.append((self.t, self.state(), self.ex.segment.kind))


Step = Callable[[Run], None]


def feed(ball: Ball | None, until: float) -> Step:
    """Tick setpoints every ``DT`` up to ``until`` [s]; deliver the 50 Hz detections of ``ball``
    (None: nothing seen) whose stamp plus ``LATENCY`` has come, each with the fixed noise."""

    def step(run: Run) -> None:
        while run.t < until - 1e-9:
            run.t += DT
            while run.stamp + LATENCY <= run.t + 1e-9:
                p = None if ball is None else ball.at(run.stamp)
                if p is not None:
                    run.ex.on_detection(run.t, run.stamp, p + run.rng.normal(0.0, NOISE, 3))
                    run.note()
                run.stamp = round(run.stamp + FRAME, 9)
            run.q, _ = run.ex.setpoint(run.t)
            run.note()

    return step


def tick(until: float) -> Step:
    """Setpoints only, nothing seen, up to ``until`` [s]."""
    return feed(None, until)


class Pose(NamedTuple):
    """Joints (6,) given as offsets [rad] from the robot's home."""

    offset: tuple[float, ...] = (0.0,) * 6


HOME = Pose()
NEAR_HOME = Pose((5e-4,) * 6)  # within the executor's home tolerance (1e-3 rad)
OFF_HOME = Pose((0.3, -0.2, 0.2, 0.0, 0.2, 0.0))  # well away from home, within the limits
WRIST_OFF = Pose((0.0, 0.0, 0.0, 0.3, 0.0, 0.0))  # arm home, wrist away
ZERO = np.zeros(6)
UNPLANNABLE = np.r_[1e4, 1e4, 1e4, 0.0, 0.0, 0.0]  # rad/s: Ruckig plans nothing from here


def _arg(run: Run, a):
    """``"here"``: the last commanded joints; a :class:`Pose`: its joints; else ``a``."""
    if isinstance(a, str) and a == "here":
        return run.q.copy()
    if isinstance(a, Pose):
        return run.ex.robot.home + np.array(a.offset)
    return a


def start_from(pose: Pose, home_on_start: bool = True) -> Step:
    def step(run: Run) -> None:
        run.ex.home_on_start = home_on_start
        run.ex.start_from(_arg(run, pose), run.t)
        run.note()

    return step


def call(name: str, *args) -> Step:
    """``ex.name(*args, t)`` at the script's time (arguments as :func:`_arg` reads them)."""

    def step(run: Run) -> None:
        getattr(run.ex, name)(*(_arg(run, a) for a in args), run.t)
        run.note()

    return step


# situations: real calls that bring a fresh executor (at t = 0) where a row starts
AT_HOME = (start_from(HOME),)
TRACKING_HELD = (*AT_HOME, feed(HELD, 0.8))
EXECUTING_THROW = (*AT_HOME, feed(THROW, RELEASE + 0.3))
RETURNING_THROW = (*EXECUTING_THROW, feed(THROW, END + 0.1))  # on the way home from the throw
FAULTED = (*EXECUTING_THROW, call("hold_fault", "here"))
AWAY_START = (start_from(OFF_HOME, home_on_start=False),)
RETURNING_OFF = (start_from(OFF_HOME), tick(0.3))  # half way home from OFF_HOME


class Row(NamedTuple):
    """One transition: situation, script, and what must be seen after the script.

    ``modes``: states seen during the script, in order, the first one the state it starts in.
    ``enter``: (state, lo, hi): the script's last state was entered within [lo, hi] [s];
    ``enter_kind``: the segment kind (or kinds) commanded when it was entered.
    ``kind``: the segment kind (or kinds) commanded at the end; ``episodes``: finished throws;
    ``t_start``: the current throw started moving; ``seen``: detections in the filter;
    ``fed``: a detection of the script reached the filter; ``at_home``: the last setpoint is
    home (joints 1-3 within 1e-6 rad, the wrist 1e-3 rad). None: not checked. ``xfail``: why
    the row fails today (a known mismatch with the documented behaviour; strict).
    """

    name: str
    planner: str
    situation: tuple[Step, ...]
    script: tuple[Step, ...]
    modes: tuple[str, ...]
    kind: str | tuple[str, ...] | None = None
    episodes: int | None = None
    t_start: bool | None = None
    seen: int | None = None
    fed: bool | None = None
    at_home: bool | None = None
    enter: tuple[str, float, float] | None = None
    enter_kind: str | tuple[str, ...] | None = None
    cfg: RunConfig = CFG
    xfail: str | None = None


def _throw_row(planner: str, kinds: tuple[str, ...], cfg: RunConfig = CFG) -> Row:
    """tracking -> executing: a throw confirmed as approaching, the arm leaves home in flight
    on a segment of one of ``kinds``; the planners that re-target at every belief end on a
    move to a goal."""
    return Row(
        f"tracking->executing:throw[{planner}{'' if cfg is CFG else ',no-launch'}]",
        planner,
        AT_HOME,
        (feed(THROW, RELEASE + 0.35),),
        (IDLE, TRACKING, EXECUTING),
        kind=STEER,
        enter_kind=kinds,
        episodes=0,
        t_start=True,
        enter=(EXECUTING, RELEASE, RELEASE + 0.3),  # after the release, well before the plane
        cfg=cfg,
    )


WIDE = Ball(aim=(2.6, 0.9))  # crosses 1.1 m beside the goal grid's margin
LOB = Ball(flight=1.4, t_lost=RELEASE + 0.3)  # a slow lob lost from view 0.3 s after release

ROWS = [
    Row(
        "idle->tracking:first detection",
        "tree",
        AT_HOME,
        (feed(HELD, 0.5 + LATENCY + DT),),
        (IDLE, TRACKING),
        kind=HOLD,
        t_start=False,
        seen=1,
        fed=True,
        enter=(TRACKING, 0.5 + LATENCY, 0.5 + LATENCY + DT),
    ),
    *(
        Row(
            f"tracking:held ball never confirms{suffix}",
            planner,
            TRACKING_HELD,
            (feed(HELD, 2.5),),
            (TRACKING,),
            kind=HOLD,
            t_start=False,
            at_home=True,
        )
        for planner, suffix in (("tree", ""), ("naive-paper", "[naive-paper]"))
    ),
    Row(
        "tracking->idle:silence after a held ball",
        "tree",
        AT_HOME,
        (feed(Ball(release=math.inf, t_lost=1.0), 1.6),),
        (IDLE, TRACKING, IDLE),
        kind=HOLD,
        episodes=0,
        t_start=False,
        seen=0,
        # the last stamp is 0.98 s; silence counts from it plus stamp_lag
        enter=(IDLE, 0.98 + TH.stamp_lag + TH.detection_timeout, 0.98 + 0.3 + 2 * DT),
    ),
    Row(
        "tracking->idle:a throw wide of the goals never confirms",
        "tree",
        AT_HOME,
        (feed(WIDE, CROSS + 0.5),),
        (IDLE, TRACKING, IDLE),
        episodes=0,
        t_start=False,
        at_home=True,
    ),
    _throw_row("tree", (STEER,)),
    _throw_row("naive", (STEER,)),
    _throw_row("naive-paper", (STEER,)),
    _throw_row("tree-rest", (EDGE, TERMINAL)),
    _throw_row("naive", (STEER,), NO_LAUNCH),
    Row(
        "executing->returning:after the predicted crossing",
        "tree",
        EXECUTING_THROW,
        (feed(THROW, END + 0.03),),
        (EXECUTING, RETURNING),
        kind=RETURN,
        episodes=0,
        t_start=True,
        enter=(RETURNING, END - 0.01, END + 0.02),
    ),
    Row(
        "executing->returning:lost from view, at the predicted crossing",
        "naive",
        EXECUTING_THROW,
        (feed(Ball(t_lost=RELEASE + 0.3), END + 0.03),),
        (EXECUTING, RETURNING),
        kind=RETURN,
        enter=(RETURNING, END - 0.01, END + 0.02),  # not at the detection timeout
    ),
    Row(
        "executing->returning:blind for max_blind",
        "naive",
        AT_HOME,
        (feed(LOB, RELEASE + 0.3 + TH.stamp_lag + TH.max_blind + 0.05),),
        (IDLE, TRACKING, EXECUTING, RETURNING),
        kind=RETURN,
        t_start=True,
        # last stamp 1.28 s; the lob's crossing (2.4 s) is still ahead then
        enter=(RETURNING, 1.28 + TH.stamp_lag + TH.max_blind, 1.28 + 0.05 + 1.0 + 2 * DT),
    ),
    Row(
        "returning->idle:arm and wrist home",
        "tree",
        RETURNING_THROW,
        (tick(5.0),),
        (RETURNING, IDLE),
        kind=HOLD,
        episodes=1,
        t_start=False,
        seen=0,
        at_home=True,
    ),
    Row(
        "returning->idle:waits for the wrist",
        "naive",
        (*AT_HOME, tick(0.2)),
        (call("recover", WRIST_OFF), tick(1.5)),
        (IDLE, RETURNING, IDLE),
        kind=HOLD,
        at_home=True,
        enter=(IDLE, 0.3, 1.5),  # the arm is home at once, the wrist turns 0.3 rad
    ),
    Row(
        "returning:a detection is ignored",
        "tree",
        RETURNING_THROW,
        (feed(HELD, END + 0.25),),
        (RETURNING,),
        kind=RETURN,
        episodes=0,
        fed=False,
    ),
    Row(
        "returning:a resync Ruckig cannot plan from leaves a hold",
        "naive",
        RETURNING_OFF,
        (call("resync", "here", UNPLANNABLE, ZERO),),
        (RETURNING,),
        kind=HOLD,
    ),
    Row(
        "returning:replans the way home after a resync left a hold",
        "naive",
        (*RETURNING_OFF, call("resync", "here", UNPLANNABLE, ZERO)),
        (tick(5.0),),
        (RETURNING, IDLE),
        kind=HOLD,
        at_home=True,
    ),
    Row(
        "returning:replans the way home after a resync",
        "naive",
        RETURNING_OFF,
        (call("resync", "here", ZERO, ZERO),),
        (RETURNING,),
        kind=RETURN,
        at_home=False,
    ),
    Row(
        "idle->fault:hold_fault",
        "tree",
        AT_HOME,
        (call("hold_fault", "here"),),
        (IDLE, FAULT),
        episodes=0,
    ),
    Row(
        "tracking->fault:hold_fault",
        "tree",
        TRACKING_HELD,
        (call("hold_fault", "here"),),
        (TRACKING, FAULT),
        episodes=0,
        seen=0,
    ),
    Row(
        "executing->fault:hold_fault",
        "tree",
        EXECUTING_THROW,
        (call("hold_fault", "here"), tick(RELEASE + 0.5)),
        (EXECUTING, FAULT),
        episodes=1,  # the confirmed throw was dropped
        t_start=False,
        seen=0,
    ),
    Row(
        "returning->fault:hold_fault",
        "tree",
        RETURNING_THROW,
        (call("hold_fault", "here"), tick(END + 1.0)),
        (RETURNING, FAULT),
        episodes=1,
    ),
    Row(
        "fault:holds where it was stopped, from executing",
        "tree",
        EXECUTING_THROW,
        (call("hold_fault", "here"), tick(RELEASE + 0.5)),
        (EXECUTING, FAULT),
        kind=HOLD,
    ),
    Row(
        "fault:holds where it was stopped, from returning",
        "tree",
        RETURNING_THROW,
        (call("hold_fault", "here"), tick(END + 1.0)),
        (RETURNING, FAULT),
        kind=HOLD,
        at_home=False,
    ),
    Row(
        "fault:detections and time are ignored",
        "naive",
        FAULTED,
        (feed(Ball(hand=(7.5, 0.2, 1.4), release=RELEASE + 1.0, t_seen=1.4), RELEASE + 2.0),),
        (FAULT,),
        fed=False,
        seen=0,
        t_start=False,
    ),
    Row(
        "fault->idle:restart at home",
        "naive",
        (*AT_HOME, call("hold_fault", HOME)),
        (start_from(HOME), feed(HELD, 0.6)),
        (FAULT, IDLE, TRACKING),
        kind=HOLD,
    ),
    Row(
        "executing->returning:recover",
        "tree",
        EXECUTING_THROW,
        (call("recover", "here"),),
        (EXECUTING, RETURNING),
        kind=RETURN,
        episodes=1,  # the dropped throw counts
        t_start=False,
        seen=0,
    ),
    Row(
        "executing->returning->idle:recover, home",
        "tree",
        EXECUTING_THROW,
        (call("recover", "here"), tick(4.0)),
        (EXECUTING, RETURNING, IDLE),
        kind=HOLD,
        episodes=1,
        at_home=True,
    ),
    Row(
        "start at home:idle, not away",
        "tree",
        (),
        (start_from(NEAR_HOME, home_on_start=False), feed(HELD, 0.6)),
        (IDLE, TRACKING),
        kind=HOLD,
    ),
    Row(
        "start away:away, detections ignored",
        "tree",
        AWAY_START,
        (feed(THROW, CROSS + 0.5),),
        (AWAY,),
        kind=HOLD,
        seen=0,
        fed=False,
        t_start=False,
        at_home=False,
    ),
    Row(
        "away->returning->idle:go_home",
        "tree",
        AWAY_START,
        (tick(0.3), call("go_home"), tick(4.0), feed(HELD, 4.2)),
        (AWAY, RETURNING, IDLE, TRACKING),
        kind=HOLD,
    ),
    Row(
        "start away with home_on_start:returning->idle",
        "tree",
        (),
        (start_from(OFF_HOME), tick(4.0)),
        (IDLE, RETURNING, IDLE),
        kind=HOLD,
        at_home=True,
    ),
]


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


def test_the_table_names_its_rows_once():
    names = [row.name for row in ROWS]
    assert len(set(names)) == len(names)


def _param(row: Row):
    marks = () if row.xfail is None else pytest.mark.xfail(strict=True, reason=row.xfail)
    return pytest.param(row, id=row.name, marks=marks)


@pytest.mark.parametrize("row", [_param(row) for row in ROWS])
def test_transition(row: Row, rtree, robot):
    ex = Executor(rtree, robot, row.cfg, row.planner)
    run = Run(ex, seed=7)
    for step in row.situation:
        step(run)
    run.log = []
    run.note()
    t_det = ex.t_last_det
    for step in row.script:
        step(run)
    modes = tuple(m for _, m, _ in run.log)
    assert modes == row.modes, run.log
    if row.enter is not None:
        state, lo, hi = row.enter
        assert run.log[-1][1] == state, run.log
        assert lo <= run.log[-1][0] <= hi, run.log
    if row.enter_kind is not None:
        assert run.log[-1][2] in _kinds(row.enter_kind), run.log
    if row.kind is not None:
        assert ex.segment.kind in _kinds(row.kind)
    if row.episodes is not None:
        assert ex.episodes == row.episodes
    if row.t_start is not None:
        assert (not math.isnan(ex.episode.t_start)) == row.t_start
    if row.seen is not None:
        assert ex.belief.n_meas == row.seen
    if row.fed is not None:
        assert (ex.t_last_det != t_det) == row.fed
    if row.at_home is not None:
        off = run.q - robot.home
        home = np.all(np.abs(off[:3]) < 1e-6) and np.all(
            np.abs(off[3:]) < CFG.execution.wrist_home_tolerance
        )
        assert home == row.at_home, off


def _kinds(kind: str | tuple[str, ...]) -> tuple[str, ...]:
    return (kind,) if isinstance(kind, str) else kind


# ---------------------------------------------------------------- limits of re-planned moves
def _speeding_up(rtree, robot, scale: float = 0.2):
    """An executor at ``--speed-scale`` ``scale`` whose arm is on a long move of the full
    limits (joint 1 by 1.2 rad), and a time at which joint 1 is still speeding up close to its
    velocity limit."""
    from thinkfast.control.segments import move
    from thinkfast.daemon.cli import scale_limits
    from thinkfast.robot.steering import state_at

    slow = scale_limits(robot, scale)
    ex = Executor(rtree, slow, CFG, "naive")
    ex.start_from(slow.home, 0.0)
    tl = ex.timeline
    target = slow.home[:3] + np.array([1.2, 0.0, 0.0])
    tl.segment = move(tl.steer, STEER, tl.state(0.0), target, 0.0)
    ex.mode = EXECUTING
    traj, v_max = tl.segment.traj, tl.steer.v_max[0]
    for t in np.arange(0.0, traj.duration, DT):
        _, v, a = state_at(traj, t).reshape(3, 3)
        if abs(v[0]) > 0.9 * v_max and a[0] * v[0] > 0.0:
            return ex, float(t)
    raise AssertionError("the move never speeds up near the limit")


def test_a_resync_from_an_acceleration_no_plan_holds_stays_within_the_velocity_limit(rtree, robot):
    """After a missed cycle the control core resumes from the supervisor's extrapolated
    acceleration: one that would carry the speed past the limit is taken as the largest a
    plan could have, for the arm and the wrist alike."""
    from thinkfast.robot.steering import peaks

    ex, t = _speeding_up(rtree, robot)
    s, steer = ex.segment.state(t), ex.timeline.steer
    w_v = 0.95 * ex.wrist.steer.v_max
    qd = np.r_[s[3:6], w_v]
    qdd = np.r_[s[6:9] * 3.0, ex.wrist.steer.a_max]  # both speeding up harder than a plan can
    ex.resync(np.r_[s[:3], ex.wrist.state[:3]], qd, qdd, t)
    assert ex.segment.kind == STEER
    assert np.all(peaks(ex.segment.traj)[0] <= steer.v_max * (1 + 1e-9))
    for k in range(1, 200):
        w = ex.wrist.step(t + k * DT, ex.segment.state(t + k * DT)[:3], np.array([1.0, 0, 0]))
        assert np.all(np.abs(w[3:6]) <= ex.wrist.steer.v_max * (1 + 1e-9)), k
