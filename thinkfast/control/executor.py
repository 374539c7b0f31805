"""Throw episodes as a state machine: idle -> tracking -> executing -> returning -> idle.

Pure logic, no I/O and no clock reads: the control core (:mod:`thinkfast.control.core`, driven
by the daemon and by the lockstep simulator) feeds it detections (``on_detection``) and asks for
the setpoint of every 4 ms tick (``setpoint``), both with the time the plans run on. States
(:class:`Mode`; tests/test_executor_modes.py drives every transition):

- ``idle``: at home, no ball. The first detection starts ``tracking``.
- ``tracking``: the filter follows the ball (started afresh when the previous detection is older
  than ``throw.detection_timeout``). A belief *predicts a throw* when the ball approaches the
  plane faster than ``min_approach_speed`` at ``approach_sigmas``, its crossing is due within
  ``max_tau`` and lies within ``region_margin`` of the goal grid; a ball held still never does.
  Once the filter has absorbed ``settle_updates`` updates since its last (re)start, each belief
  that predicts a throw adds one to a count and each one that does not takes one off (never
  below zero: one outlier frame costs one step, not the whole count); the throw is confirmed
  when the count reaches ``confirm_updates``. A launch found by the launch detector
  (``[launch]``) restarts the filter from its fit, and confirms at once when that belief
  predicts a throw. From the confirmation on, every belief goes to the planner, which leaves
  home (``executing``) as below. No detection for ``detection_timeout`` (counted from the last
  stamp plus ``stamp_lag``) ends the episode: back to ``idle``.
  *Hedge stage* (tree planner, ``[hedge] mode`` not ``none``; :mod:`thinkfast.control.hedge`):
  before the confirmation, once the early belief makes a launch likely, the arm may start on a
  move kept within ``[hedge] bound`` of home (``stage`` = ``hedge``); a hedge given up
  (``hedge_end``: ``no_launch``, ``timeout``, ``silence``) returns home while still tracking
  (the episode ends only once the arm is home); at the confirmation the planner takes over from
  the commanded state (``stage`` = ``commit``, mode ``executing`` when the arm is off home).
- ``executing``: what the planner does at every belief from the confirmation on:
  - ``tree`` (the re-rooted choice, :mod:`thinkfast.decide.choice`): the best of continuing
    the motion in progress (at home: waiting there), direct moves to goals and (``[choice]
    branches``) the compiled child edges of the node the arm is at; a move or a branch replaces
    continuing only when it is worth ``switch_margin`` more. When continuing wins but is worth
    less than ``min_move_value`` (the ball comes too fast for any move to help), it rushes to
    the goal nearest the most likely crossing point, as ``naive`` does.
  - ``tree-rest`` (the paper's at-rest tree): the arm leaves home once the root of the at-rest
    backup blocks with at least ``min_move_value`` and its best first edge is not "stay"; every
    ``eps`` it takes the best child of the node it reaches (a primitive in progress is finished), or
    commits to the node's best terminal edge when that is worth more. Once committed, every belief
    re-targets Ruckig to the most probable goal when it differs from the committed one (the tree is
    exhausted: the paper's fallback). When the root is worth less than ``min_move_value``, it rushes
    to the most probable goal, re-targeted at every belief.
  - ``naive``: at every belief, Ruckig from the commanded state to the goal nearest the most likely
    crossing point (it leaves home at the confirmation).
  - ``naive-paper`` (the paper's baseline): the same, from the first belief that predicts a throw at
    zero sigmas (mean approach speed), with neither the launch detector, the settling nor the count.
  A throw ends (``returning``) at the first tick after its predicted crossing plus
  ``controller_lag`` plus ``after_crossing``, after ``max_blind`` without a detection, or after
  ``detection_timeout`` without one when no crossing was ever predicted: a silence alone does not
  end a throw whose crossing is still ahead (the ball may leave the camera's view before the plane).
- ``returning``: detections are ignored; a move home within the return limits
  (``return_speed_scale``; the full limits when those cannot brake it). When the way home ends
  elsewhere, was replaced by a hold (a :meth:`resync` Ruckig could not plan) or was never
  planned, it is planned again from the commanded state. ``idle`` once joints 1-3 are home at
  rest and the wrist is home (``wrist_home_tolerance``, ``wrist_home_speed``), or
  ``wrist_home_timeout`` after the arm's way home ended.
- away from home at start (``away``; the mode is ``idle``): :meth:`start_from` further than
  ``HOME_TOLERANCE`` from home. With ``home_on_start`` (the simulators) the arm returns home at
  once; without it (the daemon, unless ``--go-home``) it holds where it stands and ignores
  balls until :meth:`go_home` (called once the way home was checked against the cell) or until
  it starts again at home.
- ``fault``: :meth:`hold_fault`, called by the control core once supervisor faults repeat
  (latched): the throw is dropped, detections are ignored and no tick changes the mode; only a
  restart (:meth:`start_from`) leaves it. The setpoints hold the position where the arm was
  stopped (and the core keeps its supervisor braked). A single fault is recovered from:
  :meth:`recover` drops the throw and returns home
  from where the arm was stopped.

A confirmed throw is counted in ``episodes`` (and kept as ``last_episode``) when its episode is
dropped: back at ``idle``, at a fault, a recovery or a restart.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.hedge import COMMIT, HEDGE, Hedger
from thinkfast.control.segments import (
    EDGE,
    HOLD,
    RETURN,
    STEER,
    TERMINAL,
    Segment,
    WristTracker,
    hold,
    move,
)
from thinkfast.decide.branches import BranchTable
from thinkfast.decide.choice import BRANCH, DIRECT, BranchPoint, Chooser
from thinkfast.decide.tree_view import Decision, RuntimeTree
from thinkfast.estimate import filter as kf
from thinkfast.estimate.fusion import DEFAULT_CAMERA, CameraCheck, camera_filter
from thinkfast.estimate.launch import LaunchDetector
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import Steering


class Mode(enum.StrEnum):
    """State of the executor (its value is the status ``state`` and the setpoints' ``mode``)."""

    IDLE = "idle"
    TRACKING = "tracking"
    EXECUTING = "executing"
    RETURNING = "returning"
    FAULT = "fault"


IDLE, TRACKING, EXECUTING, RETURNING, FAULT = Mode  # the names the rest of the package uses
HOME_TOLERANCE = 1e-3  # rad: a joint further than this from home is away from home
ARM_HOME = 1e-6  # rad, rad/s: the commanded way home has ended (Ruckig lands within 1e-8)
PLANNERS = ("tree", "tree-rest", "naive", "naive-paper")  # the ones the executor runs (online)


@dataclass
class EpisodeLog:
    """What the current throw did (for status, records and the judge)."""

    t_confirmed: float = math.nan
    t_start: float = math.nan
    t_cross: float = math.nan
    path: list[int] = field(default_factory=list)  # tree nodes reached
    terminal: int = -1
    chosen_value: float = math.nan
    decisions: int = 0
    t_hedge: float = math.nan  # when the first hedge of the throw began (nan: none)


class Executor:
    """Planner and executor of one robot (see the module doc).

    Args:
        tree: the runtime tree.
        robot: the robot (limits, home).
        cfg: runtime configuration.
        planner: one of :data:`PLANNERS`.
    """

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, planner: str = "tree"):
        if planner not in PLANNERS:
            raise ValueError(f"planner {planner!r} is not one of {', '.join(PLANNERS)}")
        self.tree, self.robot, self.cfg, self.planner = tree, robot, cfg, planner
        self.steer = Steering(robot.v_max[:3], robot.a_max[:3], robot.j_max[:3])
        scale = cfg.execution.return_speed_scale
        self.steer_home = Steering(
            robot.v_max[:3] * scale, robot.a_max[:3] * scale, robot.j_max[:3] * scale
        )
        # wrist targets stay further inside the limits than the supervisor's margin, so a wrist
        # still moving at its target never trips the supervisor's position clamp
        self.wrist = WristTracker(
            robot,
            cfg.execution.wrist_max_tilt,
            cfg.safety.position_margin + cfg.execution.wrist_inner_margin,
        )
        self.lag = cfg.execution.controller_lag
        self.chooser = None
        if planner == "tree":
            self.chooser = Chooser(
                tree.goal_q, tree.goal_yz, robot, tree.plane_x, tree.ball_radius, self.steer,
                cfg.choice, cfg.path_value,
            )  # fmt: skip
        self.branches = None
        if self.chooser is not None and cfg.choice.branches:
            self.branches = branch_table(tree, self.chooser.geom, cfg.choice.branch_per_goal)
        self.pending: tuple[int, float] | None = None  # (child node, wall time it starts)
        self.hedger = None  # the hedge stage (control/hedge.py): the tree planner only
        if planner == "tree" and cfg.hedge.mode != "none" and cfg.launch.enabled:
            h = cfg.hedge
            self.hedger = Hedger(
                tree, robot, self.steer, h, cfg.early, cfg.filter.gravity, self.lag
            )
        self.stage = ""  # "", HEDGE or COMMIT: the stage of the current throw (status)
        self.hedge_end = ""  # why the last hedge ended: confirmed, no_launch, timeout, silence
        self.hedge_t0 = -np.inf  # when the hedge in progress began
        self.hedges = 0  # hedges begun since the start
        self.hedge_off = False  # no more hedges in this episode (one timed out)
        self.home_after = False  # a given-up hedge goes home once its move ends
        self.sensor = np.array(cfg.camera.xyz, dtype=float)  # camera origin in base
        n_cam = 1 + len(cfg.cameras)
        window = cfg.fusion.launch_window if cfg.cameras else None
        self.launch = LaunchDetector(cfg.launch, cfg.filter, self.sensor, n_cam, window)
        # several cameras (docs/CAMERAS.md): each one's origin and noise model, and the check
        # that keeps a camera with a wrong extrinsic out; None with the default camera alone
        self.sensors: dict[str | None, tuple[np.ndarray, kf.FilterConfig]] = {
            None: (self.sensor, cfg.filter)
        }
        self.check: CameraCheck | None = None
        if cfg.cameras:
            for c in cfg.cameras:
                self.sensors[c.id] = (np.array(c.xyz, dtype=float), camera_filter(cfg.filter, c))
            ref = None if cfg.fusion.reference == DEFAULT_CAMERA else cfg.fusion.reference
            self.reference = ref
            origin, fcfg = self.sensors[ref]
            self.check = CameraCheck(cfg.fusion, fcfg, origin, cfg.throw.detection_timeout)
        self.mode = IDLE
        self.belief = kf.empty(cfg.filter)
        self.decision: Decision | None = None
        self.chosen: tuple[float, int] | None = None  # tree planner: (value, goal) of its choice
        self.segment = hold(np.r_[robot.home[:3], np.zeros(6)], -np.inf)
        self.node = 0
        self.confirm = 0
        self.settled = 0
        self.t_last_det = -np.inf
        self.episode = EpisodeLog()
        self.last_episode: EpisodeLog | None = None  # the last confirmed throw, once it ended
        self.episodes = 0
        self.wrist.reset(robot.home[3:], -np.inf)
        self.home_on_start = True  # away from home at start: go home at once (module doc)
        self.away = False  # holding away from home, balls ignored, until go_home

    # ---------------------------------------------------------------- measurements
    def on_detection(
        self, t_now: float, stamp: float, p_base: np.ndarray, camera: str | None = None
    ) -> str | None:
        """Fuse a detection (ball centre in ``base`` [m], captured at ``stamp``) at ``t_now``;
        ``camera`` is the id of the camera that took it (None: the default camera). Returns
        ``"inconsistent_camera"`` when that camera's detections are refused (docs/CAMERAS.md),
        else None."""
        if self.mode in (RETURNING, FAULT) or self.away:
            return None
        sensor, fcfg = self.sensors[camera]
        if self.check is not None:
            if camera == self.reference:
                self.check.reference(stamp, p_base)
            elif not self.check.admit(camera, stamp, p_base, kf.stereo_r(p_base, sensor, fcfg)):
                return "inconsistent_camera" if self.check.state(camera).inconsistent else None
        if stamp - self.t_last_det > self.cfg.throw.detection_timeout:
            self.belief = kf.empty(self.cfg.filter)  # a new ball: start the filter afresh
            self.confirm = 0
            self.launch.reset()
        lag = self.cfg.fusion.max_lag if self.check is not None else 0.0
        self.belief, info = kf.update(self.belief, stamp, p_base, fcfg, sensor, lag)
        if info.status == "late":
            return None
        self.t_last_det = max(self.t_last_det, stamp)
        # updates absorbed since the filter last (re)started from two measurements: before 2,
        # one outlier among those two can fake any velocity
        restarted = info.status in ("first", "init") or bool(np.any(info.reset))
        self.settled = 0 if restarted else self.settled + 1
        launched = False
        paper = self.planner == "naive-paper"  # no launch gate: the filter alone
        if self.mode in (IDLE, TRACKING) and self.cfg.launch.enabled and not paper:
            several = self.check is not None
            fit = self.launch.add(stamp, p_base, *((sensor, fcfg) if several else ()))
            if fit is not None:  # the launch fit replaces the filter's slower restart
                newest = None if fit.t != stamp or not several else sensor
                self.belief = kf.restart(self.belief, fit.t, fit.mean, fit.cov, fit.z, newest)
                self.settled = max(self.settled, self.cfg.throw.settle_updates)
                launched = True
        if self.mode == IDLE:
            self.mode = TRACKING
        if self.belief.n_meas < 2:
            return
        c = self.tree.crossing(self.belief.mean, self.belief.cov, self.cfg.filter.gravity)
        if c.ok:
            self.episode.t_cross = stamp + float(c.mean[2])
        if paper:
            if self.mode == TRACKING and not self._approaching(c, sigmas=0.0):
                return  # the paper's baseline acts from the first belief predicting a crossing
            if math.isnan(self.episode.t_confirmed):
                self.episode.t_confirmed = t_now
        elif self.mode == TRACKING:
            if self.settled >= self.cfg.throw.settle_updates and self._approaching(c):
                self.confirm = self.cfg.throw.confirm_updates if launched else self.confirm + 1
            else:  # one outlier frame costs one step, not the whole count
                self.confirm = max(self.confirm - 1, 0)
            if self.confirm < self.cfg.throw.confirm_updates:
                if self.hedger is not None:
                    self._hedge(t_now, stamp)
                return
            if math.isnan(self.episode.t_confirmed):
                self.episode.t_confirmed = t_now
                self._commit(t_now)
        self.episode.decisions += 1
        if self.chooser is None:  # the tree planner's choice does not need the at-rest values
            t_start = self.episode.t_start if self.mode == EXECUTING else t_now
            self.decision = self.tree.decide(c, stamp, t_start, self.lag)
        if self.planner in ("naive", "naive-paper"):
            self._naive(t_now, c)
        elif self.chooser is not None:
            self._choose(t_now, stamp, c)
        elif self.mode == TRACKING:
            self._maybe_leave_home(t_now)
        elif self.segment.kind in (STEER, TERMINAL):
            self._fallback(t_now)  # committed: follow the most probable goal as beliefs improve

    def current_value(self) -> tuple[float, int] | None:
        """(value, goal) of the last decision: the tree planner's choice, else the at-rest
        backup at the current node and its most probable goal; None before any."""
        if self.chosen is not None:
            return self.chosen
        d = self.decision
        if d is None or d.backup is None:
            return None
        return float(d.backup.value[self.node]), int(d.backup.best_goal)

    def _approaching(self, c, sigmas: float | None = None) -> bool:
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

    # ---------------------------------------------------------------- hedge stage
    def _hedge(self, t_now: float, stamp: float) -> None:
        """Before the confirmation: start, re-plan or end a hedge on the early belief."""
        if self.hedge_off or self.mode != TRACKING:
            return
        fit, c = self.hedger.belief(list(self.launch.points))
        if fit is None:
            if self.stage == HEDGE:
                self._end_hedge(t_now, "no_launch")
            return
        seg = self.hedger.plan(
            self.segment.state(t_now), self.hedger.target(c, stamp, t_now), t_now
        )
        if seg is None:
            return  # the move in progress stays (it is within the bound)
        self.home_after = False
        if self.stage != HEDGE:
            self.stage, self.hedge_t0 = HEDGE, t_now
            self.hedges += 1
            if math.isnan(self.episode.t_hedge):
                self.episode.t_hedge = t_now
        self.segment = seg
        self.pending = None

    def _hedge_tick(self, t: float, silent: bool) -> None:
        """Before the confirmation, every tick: end a hedge at its time limit or when the ball is
        lost; home from where a given-up hedge stopped."""
        if self.stage == HEDGE and t - self.hedge_t0 > self.cfg.hedge.timeout:
            self._end_hedge(t, "timeout")
            self.hedge_off = True
        elif self.stage == HEDGE and silent:
            self._end_hedge(t, "silence")
        if self.home_after and t >= self.segment.t_end:
            self.home_after = False
            state = self.segment.state(t)
            seg = move(self.steer_home, RETURN, state, self.robot.home[:3], t)
            self.segment = seg if seg is not None else hold(state, t)

    def _commit(self, t_now: float) -> None:
        """The launch is confirmed: the commit stage takes over from wherever the arm is."""
        if self.hedger is None:
            return
        if self.stage == HEDGE or not self._at_home(t_now):
            self.mode = EXECUTING  # the arm has left home: the episode's end brings it back
            self.episode.t_start = t_now
        if self.stage == HEDGE:
            self.hedge_end = "confirmed"
        self.stage = COMMIT
        self.home_after = False

    def _end_hedge(self, t: float, why: str) -> None:
        """Give the hedge up, still tracking the ball: home within the return limits, or the
        full ones, when that way stays within the bound (a faster hedge brakes later with the
        return limits); else on to the hedge's own target (checked) and home from there."""
        self.stage, self.hedge_end = "", why
        state = self.segment.state(t)
        self.pending = None
        for steer in (self.steer_home, self.steer):
            seg = move(steer, RETURN, state, self.robot.home[:3], t)
            if seg is not None and self.hedger.within(seg.traj):
                self.segment = seg
                return
        self.home_after = True  # the segment in progress stops within the bound

    def _at_home(self, t: float) -> bool:
        s = self.segment.state(t)
        return bool(
            np.all(np.abs(s[:3] - self.robot.home[:3]) < ARM_HOME)
            and np.all(np.abs(s[3:]) < ARM_HOME)
        )

    # ---------------------------------------------------------------- decisions
    def _maybe_leave_home(self, t_now: float) -> None:
        d = self.decision
        if d is None or d.backup is None:
            return
        b = d.backup
        if b.value[0] < self.cfg.execution.min_move_value:
            # no branch arrives in time with any chance: nothing to lose by rushing to the most
            # probable goal (a rim may still catch the ball), re-targeted at every belief
            if b.best_goal >= 0:
                self.mode = EXECUTING
                self.episode.t_start = t_now
                self.episode.chosen_value = float(b.value[0])
                self._steer_to(int(b.best_goal), t_now)
            return
        first = self._next_from(0, t_now, t_now)
        if first is None or (first.kind == EDGE and self._is_stay(first)):
            return  # waiting at home is best: decide again at the next belief
        self.mode = EXECUTING
        self.episode.t_start = t_now
        self.episode.chosen_value = float(b.value[0])
        self.segment = first

    def _is_stay(self, seg: Segment) -> bool:
        return bool(
            np.array_equal(self.tree.compiled.node_state[seg.ref], self.tree.compiled.node_state[0])
        )

    def _next_from(self, node: int, t0: float, t_now: float) -> Segment | None:
        """The segment leaving ``node`` at ``t0``: best child, or best terminal when worth more."""
        t = self.tree.compiled
        d = self.decision
        if d is None or d.backup is None:
            return None
        b = d.backup
        state = t.node_state[node]
        child, term = self.tree.best_child(d, node), self.tree.best_terminal(d, node)
        if child >= 0 and (term < 0 or b.child_value[node] >= b.term_value[node]):
            target = self.tree.subgoal_q[t.edge_target[child], :3]
            traj = self.steer.to_rest(state, target)
            if traj is not None:
                return Segment(EDGE, t0, traj, t.node_state[child], self.tree.eps, child)
        if term >= 0:
            goal = int(t.term_goal[term])
            seg = move(self.steer, TERMINAL, state, self.tree.goal_q[goal, :3], t0, term)
            if seg is not None:
                self.episode.terminal = term
                return seg
        return None

    def _advance_tree(self, t: float) -> None:
        """Switch segments at tree-edge boundaries up to wall time ``t``."""
        while self.segment.kind == EDGE and t >= self.segment.t_end:
            node = self.segment.ref
            self.node = node
            self.episode.path.append(node)
            nxt = self._next_from(node, self.segment.t_end, t)
            if nxt is None:  # no decision possible: stop at the node's state
                self.segment = hold(self.tree.compiled.node_state[node], self.segment.t_end)
                return
            self.segment = nxt

    def _fallback(self, t_now: float) -> None:
        """Tree exhausted, ball still coming: steer to the most probable goal."""
        d = self.decision
        if d is None or d.backup is None or d.backup.best_goal < 0:
            return
        goal = d.backup.best_goal
        current = self.segment.ref
        if self.segment.kind == TERMINAL:
            current = int(self.tree.compiled.term_goal[current])
        if current == goal:
            return
        self._steer_to(goal, t_now)

    def _choose(self, t_now: float, stamp: float, c) -> None:
        """Tree planner: the best of continuing, direct moves and tree branches (module doc)."""
        if not c.ok:
            return
        v = np.array(self.belief.mean[3:6], dtype=float)
        v[2] -= self.cfg.filter.gravity * float(c.mean[2])  # the ball's velocity at the plane
        at = self._branch_point(t_now)
        best, _ = self.chooser.choose(
            c.mean, c.cov, v, stamp, t_now, self.lag, self.segment.state(t_now), self.segment,
            at, self.branches,
        )  # fmt: skip
        goal = best.goal if best.kind in (DIRECT, BRANCH) else -1
        if best.kind != DIRECT and self.segment.kind == STEER:
            goal = int(self.segment.ref)  # continuing the move to this goal
        self.chosen = (float(best.value), int(goal))
        if best.kind == BRANCH:
            self._take_branch(best, at, t_now)
            return
        if best.kind != DIRECT and best.value < self.cfg.execution.min_move_value:
            # nothing reachable has value (the ball comes too fast): the paper's fallback, rush
            # to the most probable goal; a shield on its way may still catch the ball
            self._naive(t_now, c)
            return
        if best.kind != DIRECT:
            return  # continuing (at home: waiting) is worth the most
        if self.mode == TRACKING:
            self.mode = EXECUTING
            self.episode.t_start = t_now
        self.episode.chosen_value = best.value
        end = np.r_[self.tree.goal_q[best.goal, :3], np.zeros(6)]
        self.segment = Segment(STEER, t_now, best.traj, end, best.traj.duration, best.goal)
        self.pending = None

    def _branch_point(self, t_now: float) -> BranchPoint | None:
        """The tree node whose child edges can start, and when: home at rest now, or the end of
        the compiled edge in progress (still ahead); None anywhere else (off the tree)."""
        if self.branches is None:
            return None
        t = self.tree.compiled
        seg = self.segment
        if seg.kind == EDGE and t_now < seg.t0 + self.tree.eps:
            if t.child_count[seg.ref] == 0:
                return None
            pending = self.pending[0] if self.pending is not None else -1
            return BranchPoint(int(seg.ref), seg.t0 + self.tree.eps, pending)
        if np.array_equal(seg.state(t_now), t.node_state[0]):  # e.g. after a "stay" edge
            return BranchPoint(0, t_now)
        return None

    def _take_branch(self, best, at: BranchPoint, t_now: float) -> None:
        """Start the chosen child edge now (at home) or at the end of the edge in progress."""
        if self.mode == TRACKING:
            self.mode = EXECUTING
            self.episode.t_start = t_now
        self.episode.chosen_value = best.value
        if at.t_switch <= t_now:
            self._start_edge(best.node, t_now)
        else:
            self.pending = (best.node, at.t_switch)

    def _start_edge(self, child: int, t0: float) -> None:
        """Follow the compiled edge into ``child`` from the commanded state at ``t0`` (the state
        of its parent node), steering on to its sub-goal after ``eps`` unless a child of it
        is taken then."""
        t = self.tree.compiled
        target = self.tree.subgoal_q[t.edge_target[child], :3]
        traj = self.steer.to_rest(self.segment.state(t0), target)
        self.pending = None
        if traj is None:
            return
        end = np.r_[target, np.zeros(6)]
        self.segment = Segment(EDGE, t0, traj, end, traj.duration, int(child))
        self.node = int(t.node_parent[child])
        self.episode.path.append(int(child))

    def _switch_edges(self, t: float) -> None:
        """At the end of the edge in progress, start the pending child edge."""
        child, t_switch = self.pending
        seg = self.segment
        if seg.kind != EDGE or self.tree.compiled.node_parent[child] != seg.ref:
            self.pending = None  # the edge it was to follow was replaced
        elif t >= t_switch:
            self._start_edge(child, t_switch)

    def _naive(self, t_now: float, c) -> None:
        if not c.ok:
            return
        goal = self.tree.nearest_goal(c.mean[:2])
        if self.mode == TRACKING:
            self.mode = EXECUTING
            self.episode.t_start = t_now
        if self.segment.kind == STEER and self.segment.ref == goal:
            return
        self._steer_to(goal, t_now)

    def _steer_to(self, goal: int, t_now: float) -> None:
        seg = move(
            self.steer, STEER, self.segment.state(t_now), self.tree.goal_q[goal, :3], t_now, goal
        )
        if seg is not None:
            self.segment = seg
            self.pending = None

    # ---------------------------------------------------------------- ticks
    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions [rad] (6,) and velocities [rad/s] (6,) to command at wall time ``t``."""
        self._end_of_throw(t)
        if self.planner == "tree-rest" and self.mode == EXECUTING:
            self._advance_tree(t)
        elif self.pending is not None and self.mode == EXECUTING:
            self._switch_edges(t)
        s = self.segment.state(t)
        ball_v = None  # the shield turns towards the ball only in a confirmed throw
        if (
            self.mode in (TRACKING, EXECUTING)
            and self.confirm >= self.cfg.throw.confirm_updates
            and self.belief.n_meas >= 2
        ):
            v_std = np.sqrt(np.max(np.diag(self.belief.cov)[3:]))
            fast = -self.belief.mean[3] > self.cfg.throw.min_approach_speed
            if fast and v_std < self.cfg.execution.wrist_confident_speed_std:
                ball_v = self.belief.mean[3:]
        # on the way back the wrist goes to its home angles, never to the equivalent branch
        home = self.robot.home[3:] if self.mode in (RETURNING, IDLE) else None
        w = self.wrist.step(t, s[:3], self.wrist.normal_for(ball_v), home)
        if self.mode == RETURNING and (self.segment.kind != RETURN or t >= self.segment.t_end):
            arm_home = np.all(np.abs(s[:3] - self.robot.home[:3]) < ARM_HOME) and np.all(
                np.abs(s[3:]) < ARM_HOME
            )
            if not arm_home:
                # the way home ended elsewhere, was replaced by a hold (a resync) or never
                # planned (Ruckig failed): plan it again from the commanded state, or the arm
                # would wait here for good
                self._start_return(t)
            else:
                ex = self.cfg.execution
                wrist_home = np.all(np.abs(w[3:6]) < ex.wrist_home_speed) and np.all(
                    np.abs(w[:3] - self.robot.home[3:]) < ex.wrist_home_tolerance
                )
                if wrist_home or t > self.segment.t_end + ex.wrist_home_timeout:
                    self._finish_return(t)  # the whole arm is home and at rest: ready
        return np.r_[s[:3], w[:3]], np.r_[s[3:6], w[3:6]]

    def _end_of_throw(self, t: float) -> None:
        if self.mode not in (TRACKING, EXECUTING):
            return
        th = self.cfg.throw
        since = t - self.t_last_det - th.stamp_lag  # detection stamps lag the wall clock
        silent = since > th.detection_timeout
        end = self.episode.t_cross + self.lag + th.after_crossing
        crossed = t > end
        if self.mode == TRACKING and self.hedger is not None:
            self._hedge_tick(t, silent)
        if self.mode == TRACKING and silent and (self.hedger is None or self._at_home(t)):
            self._reset_episode(IDLE)  # with a hedge given up: once the arm is home
        elif self.mode == EXECUTING and (
            crossed or since > th.max_blind or (silent and math.isnan(end))
        ):
            # a silence alone does not end a throw whose crossing is still ahead: the camera may
            # lose the ball before the plane (out of view, occluded); the arm holds its plan
            self._start_return(t)

    def _start_return(self, t: float) -> None:
        state = self.segment.state(t)
        seg = move(self.steer_home, RETURN, state, self.robot.home[:3], t)
        if seg is None:  # moving faster than the return limits: brake with the full ones
            seg = move(self.steer, RETURN, state, self.robot.home[:3], t)
        self.segment = seg if seg is not None else hold(state, t)
        self.mode = RETURNING

    def _finish_return(self, t: float) -> None:
        self._reset_episode(IDLE)
        self.segment = hold(np.r_[self.robot.home[:3], np.zeros(6)], t)

    def _reset_episode(self, mode: str) -> None:
        if not math.isnan(self.episode.t_confirmed):
            self.episodes += 1
            self.last_episode = self.episode
        self.mode = mode
        self.belief = kf.empty(self.cfg.filter)
        self.decision = None
        self.chosen = None
        self.pending = None
        self.confirm = 0
        self.node = 0
        self.episode = EpisodeLog()
        self.stage = ""
        self.hedge_off = False
        self.home_after = False

    def start_from(self, q: np.ndarray, t: float) -> None:
        """Begin at the measured joints ``q`` (6,) at rest. Away from home: return there first
        with ``home_on_start``, else hold ``q`` and ignore balls until :meth:`go_home`."""
        q = np.asarray(q, dtype=float)
        self._reset_episode(IDLE)
        self.wrist.reset(q[3:], t)
        self.segment = hold(np.r_[q[:3], np.zeros(6)], t)
        self.away = bool(np.max(np.abs(q - self.robot.home)) > HOME_TOLERANCE)
        if self.away and self.home_on_start:
            self.go_home(t)

    def go_home(self, t: float) -> None:
        """Leave a hold away from home: return home within the return limits."""
        self.away = False
        self._start_return(t)

    def recover(self, q: np.ndarray, t: float) -> None:
        """After the supervisor stopped the arm at ``q`` (6,): drop the throw and return home."""
        self.resync(q, np.zeros(6), np.zeros(6), t)
        self._reset_episode(IDLE)
        self._start_return(t)

    def hold_fault(self, q: np.ndarray, t: float) -> None:
        """Latched fault: drop the throw and hold ``q`` (6,) at rest until restarted (the control
        core's braked supervisor holds the arm too; the requests say the same)."""
        q = np.asarray(q, dtype=float)
        self.wrist.reset(q[3:], t)
        self.segment = hold(np.r_[q[:3], np.zeros(6)], t)
        self._reset_episode(FAULT)

    def resync(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, t: float) -> None:
        """Continue from the commanded (or measured) state ``q, qd, qdd`` (6,) at time ``t`` [s]
        with the same intent: the motion in progress is planned again from that state (a tree
        edge, which cannot be resumed off its compiled path, becomes a move to the most
        probable goal). Used after the supervisor changed a command and after an EGM silence."""
        q, qd, qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        state = np.r_[q[:3], qd[:3], qdd[:3]]
        self.wrist.reset(q[3:], t, qd[3:], qdd[3:])
        seg = self.segment
        kind, target, ref = seg.kind, seg.end[:3], seg.ref
        self.pending = None
        if kind == EDGE and self.chooser is not None:
            kind, ref = STEER, -1  # the tree planner's edge steers on to its sub-goal: resume that
        elif kind == EDGE:
            d = self.decision
            goal = -1 if d is None or d.backup is None else int(d.backup.best_goal)
            kind, ref = STEER, goal
            target = self.tree.goal_q[goal, :3] if goal >= 0 else q[:3]
        if kind == HOLD and not state[3:].any():
            self.segment = hold(state, t)
            return
        steer = self.steer_home if kind == RETURN else self.steer
        new = move(steer, kind, state, target, t, ref)
        if new is None and steer is not self.steer:
            new = move(self.steer, kind, state, target, t, ref)
        if new is None:  # Ruckig failed: come to rest where the state would stop
            new = move(self.steer, HOLD, state, q[:3], t) or hold(state, t)
        self.segment = new


def branch_table(tree: RuntimeTree, geom, per_goal: int) -> BranchTable:
    """The tree's :class:`BranchTable`, built once per runtime tree and parameters (packing
    every continuation of the default tree takes about a second)."""
    cache = tree.__dict__.setdefault("_branch_tables", {})
    key = (geom, per_goal)
    if key not in cache:
        cache[key] = BranchTable(tree.compiled, geom, per_goal)
    return cache[key]
