"""What the optimisation planners (``mpc``, ``jpl``) share: certainty-equivalent interception
of one predicted crossing, re-solved on a receding, shrinking horizon.

A subclass predicts where and when the ball crosses the plane (:meth:`SolverPlanner.predict`)
and solves for joint 1-3 jerks over ``N`` equal intervals up to that time
(:meth:`SolverPlanner.solve`) within the arm's limits. This base does the rest, the same for
both: the timing (the plan there ``controller_lag`` before the crossing, open loop within
``freeze``), plans as cubic ``steer`` segments with a time-optimal stop, failures that never
raise (the previous plan is kept, the cause counted in :attr:`SolverPlanner.stats`), and no
hedge. Solve times are on the wall clock but decide nothing in lockstep. Units: s, m, rad.

Each of these in full: docs/DESIGN.md, "The optimisation planners", "What they share".
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.pieces import K_MAX, Pieces
from thinkfast.control.planners.base import STAY, Act, Belief, EpisodeLog, Follow, Planner
from thinkfast.control.safety_brake import stop_trajectory
from thinkfast.control.segments import STEER, Segment
from thinkfast.control.timeline import Timeline
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.robot.arm_reach import WristCentre
from thinkfast.robot.model import Robot

TERMINAL_TOLERANCE = 0.005  # m: a solution whose wrist centre misses its target by more fails
LIMIT_SHARE = 0.98  # of the velocity, acceleration and jerk limits the solvers may use
FAILURES = ("infeasible", "iterations", "error", "terminal_miss", "late", "no_stop")


class Prediction(NamedTuple):
    """Where and when the ball crosses the plane, in the plane's frame.

    Attributes:
        yz: the crossing point on the plane (2,) [m].
        t_cross: when, on the plans' clock [s].
    """

    yz: np.ndarray
    t_cross: float


class Solution(NamedTuple):
    """A solver's answer.

    Attributes:
        ok: it converged.
        reason: why not (one of :data:`FAILURES`), "" when ``ok``.
        jerk: joint 1-3 jerks (N, n) [rad/s^3], constant over each interval.
        dt: the intervals' length [s].
        iterations: solver iterations (IPOPT's, or QPs of the SCP).
    """

    ok: bool
    reason: str
    jerk: np.ndarray
    dt: float
    iterations: int = 0


@dataclass
class SolveStats:
    """What the solves did (for bench/decision.py, the status and the tests)."""

    solves: int = 0
    adopted: int = 0
    failed: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FAILURES, 0))
    frozen: int = 0  # decisions inside the freeze window (the last plan played out)
    times: list[float] = field(default_factory=list)  # wall seconds per solve (last 10,000)
    iterations: list[int] = field(default_factory=list)

    def record(self, seconds: float, iterations: int) -> None:
        self.solves += 1
        self.times.append(seconds)
        self.iterations.append(iterations)
        if len(self.times) > 10_000:
            del self.times[:1000], self.iterations[:1000]

    def as_dict(self) -> dict:
        t = np.asarray(self.times) * 1e3
        q = (lambda p: round(float(np.percentile(t, p)), 3)) if t.size else (lambda p: None)
        return {
            "solves": self.solves, "adopted": self.adopted, "frozen": self.frozen,
            "failed": {k: v for k, v in self.failed.items() if v},
            "solve_ms": {"median": q(50), "p99": q(99), "max": q(100)},
        }  # fmt: skip


def integrate(x0: np.ndarray, jerk: np.ndarray, dt: float) -> np.ndarray:
    """States (N+1, 3n) of the triple integrator from ``x0`` (3n,: p, v, a) under piecewise
    constant ``jerk`` (N, n) over intervals ``dt`` [s]: exact, as the pieces evaluate."""
    n = jerk.shape[1]
    out = np.empty((jerk.shape[0] + 1, 3 * n))
    p, v, a = (np.array(x0[i * n : (i + 1) * n], dtype=float) for i in range(3))
    out[0] = np.r_[p, v, a]
    for k, j in enumerate(jerk):
        p = p + dt * (v + dt * (a / 2 + dt * j / 6))
        v = v + dt * (a + dt * j / 2)
        a = a + dt * j
        out[k + 1] = np.r_[p, v, a]
    return out


class SolverPlanner(Planner):
    """Base of ``mpc`` and ``jpl`` (module doc). Subclasses give :meth:`predict`,
    :meth:`solve` and :attr:`settings` (their config section).

    Attributes:
        stats: the solves' counts and times.
        realtime: drop solutions that came after the deadline (the daemon sets it; lockstep
            leaves it off so that the wall clock decides nothing).
    """

    slow: ClassVar[bool] = True  # a solve may outlast an EGM cycle: online with --reply-process

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, timeline: Timeline):
        super().__init__(tree, robot, cfg, timeline)
        self.reach = WristCentre(robot)
        n = self.n_arm
        margin = cfg.safety.position_margin
        self.q_lo = np.asarray(robot.q_lower[:n], dtype=float) + 2 * margin
        self.q_hi = np.asarray(robot.q_upper[:n], dtype=float) - 2 * margin
        self.v_max = LIMIT_SHARE * np.asarray(robot.v_max[:n], dtype=float)
        self.a_max = LIMIT_SHARE * np.asarray(robot.a_max[:n], dtype=float)
        self.j_max = LIMIT_SHARE * np.asarray(robot.j_max[:n], dtype=float)
        self.normal = np.array([1.0, 0.0, 0.0])  # the plane's normal in its own frame
        self.stats = SolveStats()
        self._t_solved = -math.inf  # plans' clock time of the last solve
        self._goal_q: np.ndarray | None = None  # joints 1-3 at the crossing of the plan

    # -- what a subclass gives -----------------------------------------------------------
    settings: object  # the planner's config section

    def predict(self, b: Belief) -> Prediction | None:
        """The crossing the plan aims at (None: none predicted)."""
        raise NotImplementedError

    def solve(self, x0: np.ndarray, wc_goal: np.ndarray, horizon: float) -> Solution:
        """Jerks that take the arm from ``x0`` (3n,) to a wrist centre at ``wc_goal`` (3,) in
        ``horizon`` seconds; never raises for a numerical failure (returns ``ok`` False)."""
        raise NotImplementedError

    # -- the shared loop -----------------------------------------------------------------
    def wc_goal(self, yz: np.ndarray) -> np.ndarray:
        """The wrist centre that puts the shield's centre at the plane point ``yz``."""
        point = np.array([self.tree.plane_x, float(yz[0]), float(yz[1])])
        return self.reach.target(point, self.normal)

    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        pred = self.predict(b)
        if pred is None:
            return STAY
        horizon = pred.t_cross - self.lag - b.t_now
        s = self.settings
        if horizon < s.freeze:
            self.stats.frozen += 1
            return STAY  # the last plan plays out (at home: too late to leave)
        if b.t_now - self._t_solved < 1.0 / self.rate - 1e-9:
            return STAY  # not due: the plan in progress goes on
        self._t_solved = b.t_now
        x0 = self.timeline.state(b.t_now)
        goal = self.wc_goal(pred.yz)
        t0 = time.perf_counter()
        try:
            sol = self.solve(x0, goal, horizon)
        except Exception:  # a solver's own exception must not reach the loop
            sol = Solution(False, "error", np.zeros((0, self.n_arm)), 0.0)
        spent = time.perf_counter() - t0
        self.stats.record(spent, sol.iterations)
        if not sol.ok:
            return self._failed(sol.reason or "error")
        if spent > s.deadline and self.realtime:
            return self._failed("late")
        seg = self.segment(x0, sol, goal, b.t_now)
        if isinstance(seg, str):
            return self._failed(seg)
        self.stats.adopted += 1
        return Act(leave=True, follow=Follow(seg, None))

    @property
    def rate(self) -> float:
        return float(getattr(self.settings, "rate", 0.0) or math.inf)

    def _failed(self, reason: str) -> Act:
        self.stats.failed[reason] = self.stats.failed.get(reason, 0) + 1
        return STAY  # the previous plan stays (at home: the arm stays)

    def segment(self, x0: np.ndarray, sol: Solution, goal: np.ndarray, t0: float):
        """The solution as a ``steer`` segment from ``t0``: its exact pieces, then the
        time-optimal stop; or the failure's name."""
        n = self.n_arm
        states = integrate(x0, sol.jerk, sol.dt)
        x_end = states[-1]
        if np.linalg.norm(self.reach.position(x_end[:n]) - goal) > TERMINAL_TOLERANCE:
            return "terminal_miss"
        limits = (self.v_max / LIMIT_SHARE, self.a_max / LIMIT_SHARE, self.j_max / LIMIT_SHARE)
        stop = stop_trajectory(x_end[:n], x_end[n : 2 * n], x_end[2 * n :], limits, sync=True)
        if stop is None:
            return "no_stop"
        horizon = sol.dt * len(sol.jerk)
        s_start, s_coef = Pieces.of(stop)
        rows = []
        for k in range(n):
            head = np.c_[np.arange(len(sol.jerk)) * sol.dt, states[:-1, k], states[:-1, n + k],
                         states[:-1, 2 * n + k], sol.jerk[:, k]]  # fmt: skip
            used = np.isfinite(s_start[k])
            tail = np.c_[horizon + s_start[k, used], s_coef[k, used]]
            rows.append(np.vstack([head, tail])[:K_MAX])
        pieces = Pieces.from_rows(rows, horizon + stop.duration)
        end_q = np.asarray(stop.at_time(stop.duration)[0], dtype=float)
        self._goal_q = x_end[:n].copy()
        end = np.r_[end_q, np.zeros(2 * n)]
        return Segment(STEER, t0, pieces, end, pieces.duration, -1)

    def resume_edge(self, q: np.ndarray) -> tuple[str, np.ndarray, int]:
        """After a resync: on to rest where the plan in progress was to cross (or stop at
        ``q``)."""
        n = self.n_arm
        return STEER, (self._goal_q if self._goal_q is not None else q[:n]), -1

    def value(self) -> tuple[float, int] | None:
        return None  # certainty-equivalent: no probability of blocking to show

    def reset(self) -> None:
        super().reset()
        self._t_solved = -math.inf
        self._goal_q = None
