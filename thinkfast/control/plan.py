"""A plan as pure data, and its evaluation without the planner (the isolated reply loop).

The planner process (the daemon with its :class:`~thinkfast.control.executor.Executor`) exports
what it commands as a flat float64 vector (:func:`plan_vector`): the joint 1-3 segment in
progress and the one queued after it (each a Ruckig trajectory as its exact cubic pieces,
:class:`Pieces`), the wrist tracker's inputs (shield normal, or the angles it goes to) and the
mode. The reply process evaluates it with :class:`PlanFollower`, a stand-in for the executor
that the :class:`~thinkfast.control.core.ControlCore` drives: the setpoint at the controller's
time is the segment in effect then and the wrist tracker stepped towards its inputs, as
``Executor.setpoint`` computes them.

When the core plans again from the commanded state (a catch-up, a supervisor change, a restart,
a fault) the follower does it itself (the same :class:`~thinkfast.control.timeline.Timeline`
replan: a compiled edge steers on to its sub-goal), counts an *epoch* and records the call, so
that the planner makes the same call on its executor. A plan is taken only when it was made
after every such call (its epoch is the follower's): a plan made from a state the reply loop has
left would jump. Clock-free and without I/O.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.executor import FAULT, IDLE, RETURNING, Mode
from thinkfast.control.pieces import K_MAX, N_ARM, Pieces
from thinkfast.control.segments import EDGE, HOLD, RETURN, STEER, TERMINAL, Segment, WristTracker
from thinkfast.control.timeline import Timeline
from thinkfast.errors import RobotModelError
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import feasible_acceleration

MODES = tuple(m.value for m in Mode) + ("brake", "standby", "shadow")
KINDS = (EDGE, TERMINAL, STEER, RETURN, HOLD)
CALLS = ("resync", "start_from", "hold_fault", "recover")
# The vector's layout holds the segments of N_ARM joints and a wrist goal of N_WRIST angles:
# the split of every robot here (robot.n_arm, robot.n_joints - robot.n_arm; PlanFollower checks).
N_WRIST = 3
# a segment: kind, t0, duration, ref, end (p, v, a), the trajectory's duration, its pieces
# (start, p, v, a, j)
_SEG = 4 + 3 * N_ARM + 1 + N_ARM * K_MAX * 5
_HEAD = 3 + 3 + N_WRIST + 1  # id, epoch, mode, normal (3), goal (N_WRIST), segments
SIZE = _HEAD + 2 * _SEG


class Plan(NamedTuple):
    """A decoded plan vector: ``id``, ``epoch``, ``mode``, wrist ``normal`` (3,) and ``goal``
    (3,) or None, and the segments (current first, then the queued one) on the plans' clock."""

    id: int
    epoch: int
    mode: str
    normal: np.ndarray
    goal: np.ndarray | None
    segments: tuple[Segment, ...]


def _put_segment(out: np.ndarray, seg: Segment) -> None:
    out[:4] = (KINDS.index(seg.kind), seg.t0, seg.duration, seg.ref)
    e = 4 + 3 * N_ARM  # the end state (p, v, a) fills out[4:e]
    out[4:e] = seg.end
    out[e] = np.nan if seg.traj is None else seg.traj.duration
    if seg.traj is not None:
        start, coef = Pieces.of(seg.traj)
        n = N_ARM * K_MAX
        out[e + 1 : e + 1 + n] = start.ravel()
        out[e + 1 + n : e + 1 + 5 * n] = coef.ravel()


def _get_segment(v: np.ndarray) -> Segment:
    kind, t0, duration, ref = v[:4]
    e, traj = 4 + 3 * N_ARM, None
    if not np.isnan(v[e]):
        n, a = N_ARM * K_MAX, e + 1
        traj = Pieces(v[a : a + n].reshape(N_ARM, K_MAX),
                      v[a + n : a + 5 * n].reshape(N_ARM, K_MAX, 4), v[e])  # fmt: skip
    return Segment(KINDS[int(kind)], float(t0), traj, v[4:e].copy(), float(duration), int(ref))


def plan_vector(plan_id: int, epoch: int, mode: str, segments, normal, goal) -> np.ndarray:
    """The flat vector (:data:`SIZE`,) of a plan (see :class:`Plan`; ``segments``: 1 or 2)."""
    out = np.full(SIZE, np.nan)
    out[:3] = (plan_id, epoch, MODES.index(mode))
    out[3:6] = normal
    out[6 : 6 + N_WRIST] = np.nan if goal is None else goal
    out[_HEAD - 1] = len(segments)
    for k, seg in enumerate(segments[:2]):
        _put_segment(out[_HEAD + k * _SEG : _HEAD + (k + 1) * _SEG], seg)
    return out


def decode_plan(v: np.ndarray) -> Plan | None:
    """The :class:`Plan` of a vector from :func:`plan_vector`; None for an empty block."""
    if not math.isfinite(v[0]):
        return None
    segs = tuple(_get_segment(v[_HEAD + k * _SEG :]) for k in range(int(v[_HEAD - 1])))
    goal = None if np.isnan(v[6]) else v[6 : 6 + N_WRIST].copy()
    return Plan(int(v[0]), int(v[1]), MODES[int(v[2])], v[3:6].copy(), goal, segs)


def executor_plan(ex, plan_id: int, epoch: int) -> np.ndarray:
    """The plan vector of an :class:`~thinkfast.control.executor.Executor` now: its segment, the
    queued one when its planner can say it (``pending_segment``), its wrist inputs."""
    segs = [ex.timeline.segment]
    pending = getattr(ex.planner, "pending_segment", None)
    nxt = pending() if pending is not None else None
    if nxt is not None:
        segs.append(nxt)
    normal, goal = ex.wrist_inputs()
    return plan_vector(plan_id, epoch, ex.mode.value, segs, normal, goal)


def plan_key(ex, epoch: int) -> tuple:
    """What :func:`executor_plan` of ``ex`` depends on, in the follower's ``epoch``: the planner
    process publishes a plan when this changes."""
    tl = ex.timeline
    normal, goal = ex.wrist_inputs()
    return (id(tl.segment), tl.pending, ex.mode, normal.tobytes(),
            None if goal is None else goal.tobytes(), epoch)  # fmt: skip


class PlanFollower:
    """The executor's stand-in in the reply process: evaluates the plans it is given (module
    doc). ``calls``: ``(name, t, q, qd, qdd)`` of each replan made here, for the planner.

    Raises:
        RobotModelError: ``robot``'s split is not the plan vector's (:data:`N_ARM`,
            :data:`N_WRIST`).
    """

    def __init__(self, robot: Robot, cfg: RunConfig):
        if (robot.n_arm, robot.n_joints - robot.n_arm) != (N_ARM, N_WRIST):
            raise RobotModelError(
                f"{robot.toml_path}: a plan vector holds {N_ARM} positioning and {N_WRIST} "
                f"wrist joints, the robot has {robot.n_arm} and {robot.n_joints - robot.n_arm}"
            )
        ex = cfg.execution
        self.n_arm = robot.n_arm  # q[:n_arm]: the timeline's joints; q[n_arm:]: the wrist
        self.home = np.array(robot.home, dtype=float)
        self.timeline = Timeline(robot, ex)
        self.wrist = WristTracker(
            robot, ex.wrist_max_tilt, cfg.safety.position_margin + ex.wrist_inner_margin
        )
        self.wrist.reset(self.home[self.n_arm :], -math.inf)
        self.mode: str = IDLE
        self.away = False
        self.segments: tuple[Segment, ...] = (self.timeline.segment,)
        self.normal = self.wrist.normal_for(None)
        self.goal: np.ndarray | None = self.home[self.n_arm :]
        self.plan_id, self.epoch = -1, 0
        self.calls: list[tuple[str, float, np.ndarray, np.ndarray, np.ndarray]] = []
        self.t_set = -math.inf  # the last time a setpoint was asked for
        self._undo: tuple | None = None  # the state before the last setpoint (retract)

    def takes(self, plan: Plan) -> bool:
        """``plan`` is new and was made after every replan made here (:meth:`adopt` takes it)."""
        return plan.epoch == self.epoch and plan.id != self.plan_id

    def adopt(self, plan: Plan) -> bool:
        """Follow ``plan`` when it is new and was made after every replan made here."""
        if not self.takes(plan):
            return False
        self._undo = None
        self.plan_id, self.mode = plan.id, plan.mode
        # a plan that starts after the next cycle: the one in effect goes on until it starts
        # (it starts from that one's state then)
        early = plan.segments[0].t0 > self.t_set and self.timeline.segment.t0 <= self.t_set
        self.segments = ((self.timeline.segment,) if early else ()) + plan.segments
        self.normal, self.goal = plan.normal, plan.goal
        return True

    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions [rad] (n_joints,) and velocities [rad/s] (n_joints,) of the plan at
        ``t`` [s]."""
        self._undo = (self.t_set, self.timeline.segment, self.wrist.memo())
        segs = self.segments
        seg = segs[0]
        for later in segs[1:]:  # the last one started by t
            if t >= later.t0:
                seg = later
        self.timeline.segment = seg
        n, m = self.n_arm, self.wrist.n  # joints of the timeline, of the wrist
        s = seg.state(t)
        w = self.wrist.step(t, s[:n], self.normal, self.goal)
        self.t_set = t
        return np.r_[s[:n], w[:m]], np.r_[s[n : 2 * n], w[m : 2 * m]]

    def retract(self) -> None:
        """Undo the last :meth:`setpoint` (asked ahead for a reply that will not use it: a new
        plan, a replan or a skipped cycle came first): the follower is as if it had not been
        asked, so that the setpoint asked again is the one it would have given then. Only
        right after that call (a replan or a new plan in between forgets it)."""
        undo, self._undo = self._undo, None
        if undo is not None:
            self.t_set, self.timeline.segment, memo = undo
            self.wrist.recall(memo)

    def _replanned(self, name: str, t: float, q, qd, qdd) -> None:
        self._undo = None
        self.segments = (self.timeline.segment,)
        self.epoch += 1
        z = np.zeros(self.home.size)
        self.calls.append((name, t, np.array(q, float), z + qd, z + qdd))

    def resync(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, t: float) -> None:
        """Plan on from ``q, qd, qdd`` (n_joints,) at ``t`` with the same intent (as the
        executor)."""
        q, qd, qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        s, w, n = self.timeline.steer, self.wrist.steer, self.n_arm
        a_arm = feasible_acceleration(qd[:n], qdd[:n], s.v_max, s.a_max, s.j_max)
        a_wrist = feasible_acceleration(qd[n:], qdd[n:], w.v_max, w.a_max, w.j_max)
        self.wrist.reset(q[n:], t, qd[n:], a_wrist)
        seg = self.timeline.segment
        kind = STEER if seg.kind == EDGE else seg.kind
        self.timeline.replan(np.r_[q[:n], qd[:n], a_arm], kind, seg.end[:n], seg.ref, t)
        self._replanned("resync", t, q, qd, qdd)

    def start_from(self, q: np.ndarray, t: float) -> None:
        """Hold ``q`` (n_joints,) at rest from ``t`` (the planner decides what follows)."""
        self._hold(q, t, IDLE)
        self._replanned("start_from", t, q, 0.0, 0.0)

    def hold_fault(self, q: np.ndarray, t: float) -> None:
        """Latched fault: hold ``q`` (n_joints,) at rest."""
        self._hold(q, t, FAULT)
        self._replanned("hold_fault", t, q, 0.0, 0.0)

    def recover(self, q: np.ndarray, t: float) -> None:
        """After a fault stop at ``q`` (n_joints,): return home from there."""
        self._hold(q, t, RETURNING)
        self.timeline.start_return(t)
        self._replanned("recover", t, q, 0.0, 0.0)

    def _hold(self, q, t: float, mode: str) -> None:
        q, n = np.asarray(q, dtype=float), self.n_arm
        self.wrist.reset(q[n:], t)
        self.timeline.hold_at(q[:n], t)
        self.mode = mode
        self.normal = self.wrist.normal_for(None)  # no belief here: as the executor without one
        self.goal = self.home[n:] if mode in (IDLE, RETURNING) else None
