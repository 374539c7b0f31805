"""Throw episodes as a state machine: idle -> tracking -> executing -> returning -> idle.

Pure logic, no I/O and no clock reads: the control core (:mod:`thinkfast.control.core`) feeds it
detections (``on_detection``) and asks for the setpoint of every 4 ms tick (``setpoint``), both
with the time the plans run on (s). The executor composes the throw gate
(:mod:`thinkfast.control.gate`), the planner named in the registry
(:mod:`thinkfast.control.planners`), the hedge stage (:mod:`thinkfast.control.hedge_stage`),
the segment timeline (:mod:`thinkfast.control.timeline`) and the wrist tracker. States
(:class:`Mode`): ``idle``, ``tracking``, ``executing``, ``returning`` and ``fault`` (latched by
:meth:`hold_fault`); an arm away from home at start holds (``away``) until :meth:`go_home`,
unless ``home_on_start``.

A confirmed throw is counted in ``episodes`` when its episode is dropped; every dropped episode
is kept as ``ended``.

Every transition and what ends a throw: docs/DESIGN.md, "The control core", "Throw episodes".
"""

from __future__ import annotations

import math

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.gate import ThrowGate
from thinkfast.control.hedge_stage import hedge_stage
from thinkfast.control.modes import EXECUTING, FAULT, IDLE, RETURNING, STAGE_KEYS, TRACKING, Mode
from thinkfast.control.planners import registry
from thinkfast.control.planners.base import Belief, EpisodeLog, follow
from thinkfast.control.segments import EDGE, RETURN, Segment, WristTracker
from thinkfast.control.timeline import ARM_HOME, Timeline
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.robot.model import Robot
from thinkfast.robot.steering import feasible_acceleration

HOME_TOLERANCE = 1e-3  # rad: a joint further than this from home is away from home
__all__ = ["ARM_HOME", "STAGE_KEYS", "EpisodeLog", "Executor", "Mode"]


class Executor:
    """Throw episodes of one robot (see the module doc).

    Args:
        tree: the runtime tree.
        robot: the robot (limits, home).
        cfg: runtime configuration.
        planner: a registered planner name (:func:`thinkfast.control.planners.registry.names`).

    Attributes:
        name: the planner's name. planner: the planner. gate: the throw gate.
        timeline: the commanded joint 1-3 motion. hedge: the hedge stage (None: none).
        n_arm: ``robot.n_arm``, the timeline's joints ``q[:n_arm]`` (the wrist's: ``q[n_arm:]``).
    """

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, planner: str = "tree"):
        entry = registry.get(planner)
        cfg = entry.configure(cfg)
        self.tree, self.robot, self.cfg, self.name = tree, robot, cfg, planner
        self.n_arm = robot.n_arm  # q[:n_arm]: the timeline's joints; q[n_arm:]: the wrist
        self.timeline = Timeline(robot, cfg.execution)
        self.planner = entry.load()(tree, robot, cfg, self.timeline)
        self.gate = ThrowGate(tree, cfg, self.planner.gate)
        self.hedge = hedge_stage(self.planner, tree, robot, cfg, self.timeline)
        # wrist targets stay further inside the limits than the supervisor's margin, so a wrist
        # still moving at its target never trips the supervisor's position clamp
        self.wrist = WristTracker(
            robot,
            cfg.execution.wrist_max_tilt,
            cfg.safety.position_margin + cfg.execution.wrist_inner_margin,
        )
        self.lag = cfg.execution.controller_lag
        self.mode = IDLE
        self.episode = EpisodeLog()
        self.last_episode: EpisodeLog | None = None  # the last confirmed throw, once it ended
        self.ended: EpisodeLog | None = None  # the last episode dropped, confirmed or not
        self.episodes = 0
        self.wrist.reset(robot.home[self.n_arm :], -np.inf)
        self.home_on_start = True  # away from home at start: go home at once (module doc)
        self.away = False  # holding away from home, balls ignored, until go_home

    # ---------------------------------------------------------------- what others read
    @property
    def belief(self):
        """The ball filter's state (the gate's)."""
        return self.gate.belief

    @property
    def check(self):
        """The cameras' consistency check (None with the default camera alone)."""
        return self.gate.check

    @property
    def t_last_det(self) -> float:
        """Newest detection stamp fused [s]."""
        return self.gate.t_last_det

    @property
    def segment(self) -> Segment:
        """The joint 1-3 segment in progress."""
        return self.timeline.segment

    @property
    def node(self) -> int:
        """The tree node the motion last reached or left (0: home)."""
        return self.timeline.node

    @property
    def stage(self) -> str:
        """``""``, ``hedge`` or ``commit``: the hedge stage of the current throw."""
        return "" if self.hedge is None else self.hedge.stage

    @property
    def hedge_end(self) -> str:
        """Why the last hedge ended (``""``: none did)."""
        return "" if self.hedge is None else self.hedge.hedge_end

    @property
    def throw_end(self) -> str:
        """Why the motion of the throw under way, or else of the last one, ended: ``crossed``,
        ``blind``, ``silence``, ``retracted`` (``""``: none ended)."""
        ep = self.episode if self.episode.end or self.last_episode is None else self.last_episode
        return ep.end

    @property
    def hedges(self) -> int:
        """Hedges begun since the start."""
        return 0 if self.hedge is None else self.hedge.hedges

    def current_value(self) -> tuple[float, int] | None:
        """(value, goal) of the planner's last decision; None before any."""
        return self.planner.value()

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
        gate, ep = self.gate, self.episode
        fused = gate.fuse(stamp, p_base, camera, armed=self.mode in (IDLE, TRACKING))
        if not fused.ok:
            return fused.refusal
        if fused.retract and self.mode == EXECUTING:  # not a throw after all: stop, home
            self.timeline.stop_then_home(t_now)
            self.mode, self.episode.end = RETURNING, "retracted"
            return None
        if self.mode == IDLE:
            self.mode = TRACKING
        if gate.belief.n_meas < 2:
            return None
        c = gate.crossing()
        if c.ok:
            ep.t_cross = stamp + float(c.mean[2])
        tracking = self.mode == TRACKING
        if not gate.confirms(c, fused.launched, tracking):
            if self.hedge is not None:
                self.hedge.on_belief(t_now, stamp, list(gate.launch.points), ep)
            return None
        if math.isnan(ep.t_confirmed) and (tracking or gate.first):
            ep.t_confirmed = t_now
            if tracking and self.hedge is not None and self.hedge.commit(t_now):
                self._leave(t_now)  # the arm has left home: the episode's end brings it back
        ep.decisions += 1
        executing = self.mode == EXECUTING
        fb = gate.belief
        b = Belief(t_now, stamp, c, fb.mean, executing, ep.t_start, fb.cov, fb.r)
        act = self.planner.decide(b, ep)
        follow(self.timeline, ep, act.follow)  # the planner decides, the executor applies
        if act.leave and self.mode == TRACKING:
            self._leave(t_now)
        if act.value is not None:
            ep.chosen_value = float(act.value)
        return None

    def _leave(self, t: float) -> None:
        self.mode = EXECUTING
        self.episode.t_start = t

    # ---------------------------------------------------------------- ticks
    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions [rad] (n_joints,) and velocities [rad/s] (n_joints,) to command at
        wall time ``t``."""
        self._end_of_throw(t)
        if self.mode == EXECUTING:
            follow(self.timeline, self.episode, self.planner.advance(t, self.episode))
        n, m = self.n_arm, self.wrist.n  # joints of the timeline, of the wrist
        s = self.timeline.state(t)
        w = self.wrist.step(t, s[:n], *self.wrist_inputs())
        seg = self.timeline.segment
        if self.mode == RETURNING and (seg.kind != RETURN or t >= seg.t_end):
            arm_home = np.all(np.abs(s[:n] - self.robot.home[:n]) < ARM_HOME) and np.all(
                np.abs(s[n:]) < ARM_HOME
            )
            if not arm_home:
                # the way home ended elsewhere, was replaced by a hold (a resync) or never
                # planned (Ruckig failed): plan it again from the commanded state, or the arm
                # would wait here for good
                self._start_return(t)
            else:
                ex = self.cfg.execution
                wrist_home = np.all(np.abs(w[m : 2 * m]) < ex.wrist_home_speed) and np.all(
                    np.abs(w[:m] - self.robot.home[n:]) < ex.wrist_home_tolerance
                )
                if wrist_home or t > seg.t_end + ex.wrist_home_timeout:
                    self._finish_return(t)  # the whole arm is home and at rest: ready
        return np.r_[s[:n], w[:m]], np.r_[s[n : 2 * n], w[m : 2 * m]]

    def wrist_inputs(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(shield normal (3,), wrist angles [rad] (q[n_arm:]) to go to instead, or None): what the
        wrist tracker steps towards in the present mode and belief."""
        ball_v = None  # the shield turns towards the ball only in a confirmed throw
        belief = self.gate.belief
        if self.mode in (TRACKING, EXECUTING) and self.gate.confirmed and belief.n_meas >= 2:
            v_std = np.sqrt(np.max(np.diag(belief.cov)[3:]))
            fast = -belief.mean[3] > self.cfg.throw.min_approach_speed
            if fast and v_std < self.cfg.execution.wrist_confident_speed_std:
                ball_v = belief.mean[3:]
        # on the way back the wrist goes to its home angles, never to the equivalent branch
        home = self.robot.home[self.n_arm :] if self.mode in (RETURNING, IDLE) else None
        return self.wrist.normal_for(ball_v), home

    def retract(self) -> None:
        """Nothing is taken back: the episode moved on to the time the setpoint was asked for
        either way (:class:`~thinkfast.control.motion.Motion`; the plan follower forgets)."""

    def _end_of_throw(self, t: float) -> None:
        if self.mode not in (TRACKING, EXECUTING):
            return
        th = self.cfg.throw
        since = t - self.gate.t_last_det - th.stamp_lag  # detection stamps lag the wall clock
        silent = since > th.detection_timeout
        end = self.episode.t_cross + self.lag + th.after_crossing
        crossed = t > end
        if self.mode == TRACKING and self.hedge is not None:
            self.hedge.tick(t, silent)
        if self.mode == TRACKING and silent and (self.hedge is None or self.timeline.at_home(t)):
            self._reset_episode(IDLE)  # with a hedge given up: once the arm is home
        elif self.mode == EXECUTING:
            # a silence alone does not end a throw whose crossing is still ahead: the camera may
            # lose the ball before the plane (out of view, occluded); the arm holds its plan
            if crossed:
                self._start_return(t, "crossed")
            elif since > th.max_blind:
                self._start_return(t, "blind")
            elif silent and math.isnan(end):
                self._start_return(t, "silence")

    def _start_return(self, t: float, why: str = "") -> None:
        self.timeline.start_return(t)
        self.mode = RETURNING
        if why:
            self.episode.end = why

    def _finish_return(self, t: float) -> None:
        self._reset_episode(IDLE)
        self.timeline.hold_at(self.robot.home[: self.n_arm], t)

    def _reset_episode(self, mode: str) -> None:
        if self.episode.hedges:
            self.episode.hedge_end = self.hedge_end
        if not math.isnan(self.episode.t_confirmed):
            self.episodes += 1
            self.last_episode = self.episode
        self.ended = self.episode
        self.mode = mode
        self.gate.drop()
        self.planner.reset()
        self.timeline.drop()
        self.episode = EpisodeLog()
        if self.hedge is not None:
            self.hedge.drop()

    def start_from(self, q: np.ndarray, t: float) -> None:
        """Begin at the measured joints ``q`` (n_joints,) at rest. Away from home: return there
        first with ``home_on_start``, else hold ``q`` and ignore balls until :meth:`go_home`."""
        q, n = np.asarray(q, dtype=float), self.n_arm
        self._reset_episode(IDLE)
        self.wrist.reset(q[n:], t)
        self.timeline.hold_at(q[:n], t)
        self.away = bool(np.max(np.abs(q - self.robot.home)) > HOME_TOLERANCE)
        if self.away and self.home_on_start:
            self.go_home(t)

    def go_home(self, t: float) -> None:
        """Leave a hold away from home: return home within the return limits."""
        self.away = False
        self._start_return(t)

    def recover(self, q: np.ndarray, t: float) -> None:
        """After the supervisor stopped the arm at ``q`` (n_joints,): drop the throw and return
        home."""
        n = self.robot.n_joints
        self.resync(q, np.zeros(n), np.zeros(n), t)
        self._reset_episode(IDLE)
        self._start_return(t)

    def hold_fault(self, q: np.ndarray, t: float) -> None:
        """Latched fault: drop the throw and hold ``q`` (n_joints,) at rest until restarted (the
        control core's braked supervisor holds the arm too; the requests say the same)."""
        q, n = np.asarray(q, dtype=float), self.n_arm
        self.wrist.reset(q[n:], t)
        self.timeline.hold_at(q[:n], t)
        self._reset_episode(FAULT)

    def resync(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, t: float) -> None:
        """Continue from the commanded (or measured) state ``q, qd, qdd`` (n_joints,) at ``t`` [s]
        with the same intent: the motion in progress is planned again from that state (a tree
        edge, which cannot be resumed off its compiled path, becomes what the planner says:
        :meth:`~thinkfast.control.planners.base.Planner.resume_edge`). Used after the supervisor
        changed a command and after an EGM silence."""
        q, qd, qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        n = self.n_arm
        # an acceleration no plan of these limits would hold at that speed (one extrapolated
        # over a missed cycle, say) would carry the new plan past the velocity limit
        s, w = self.timeline.steer, self.wrist.steer
        a_arm = feasible_acceleration(qd[:n], qdd[:n], s.v_max, s.a_max, s.j_max)
        a_wrist = feasible_acceleration(qd[n:], qdd[n:], w.v_max, w.a_max, w.j_max)
        state = np.r_[q[:n], qd[:n], a_arm]
        self.wrist.reset(q[n:], t, qd[n:], a_wrist)
        seg = self.timeline.segment
        kind, target, ref = seg.kind, seg.end[:n], seg.ref
        if kind == EDGE:
            kind, target, ref = self.planner.resume_edge(q)
        self.timeline.replan(state, kind, target, ref, t)
