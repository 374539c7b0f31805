"""``mpc``: the fixed-time MPC interceptor ("Real-Time Projectile Interception with a 3-DOF
Robotic Arm and Fixed-Time MPC", github.com/aceofspades07/3dof-mpc-interceptor) on this arm.

The crossing time is the prediction's, not a decision variable: at each re-solve one nonlinear
program over ``N`` equal intervals up to it (CasADi ``nlpsol``, IPOPT), built once and
re-parameterised, warm started from the last solution shifted in time; minimum effort plus the
terminal speed, a hard terminal constraint, box constraints at every node.
:class:`~.solver_base.SolverPlanner` does the timing, the freeze, the segment and the counts.
Joint 1-3 jerks on a triple integrator, the wrist centre as the terminal point; ``mpc-soft``
(``[mpc] terminal = "soft"``) makes that point a penalty. Units: s, m, rad.

Where it differs from the design, and why: docs/DESIGN.md, "The optimisation planners", "mpc".
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.control.planners.base import Act, Belief, EpisodeLog
from thinkfast.control.planners.solver_base import Prediction, Solution, SolverPlanner
from thinkfast.control.timeline import Timeline
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.robot.model import Robot

FIT_MIN_SAMPLES = 5  # DESIGN: "Five samples is the hard minimum before the estimator returns"
FIT_MIN_SPEED = 0.1  # m/s: a fit approaching the plane slower predicts no crossing (as delta)
OK_STATUS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
INFEASIBLE_STATUS = (
    "Infeasible_Problem_Detected",
    "Restoration_Failed",
)
ITERATION_STATUS = ("Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded")


def ipopt_reason(status: str) -> str:
    """The :class:`~.solver_base.Solution` reason of an IPOPT return status ("" when solved)."""
    if status in OK_STATUS:
        return ""
    if status in INFEASIBLE_STATUS:
        return "infeasible"
    if status in ITERATION_STATUS:
        return "iterations"
    return "error"


class MpcPlanner(SolverPlanner):
    """The fixed-time MPC interceptor (module doc); ``settings`` is ``cfg.mpc``."""

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, timeline: Timeline):
        super().__init__(tree, robot, cfg, timeline)
        self.settings = cfg.mpc
        self.terminal = self.settings.terminal
        self.gravity = cfg.filter.gravity
        self._window: deque[tuple[float, np.ndarray]] = deque()  # (stamp, position) for "fit"
        self._warm: tuple[float, float, np.ndarray, np.ndarray] | None = None  # t0, dt, X, U
        self._t_now = 0.0  # the plans' clock at the decision in progress (the warm start's)
        self._build()

    # -- the nonlinear program, built once -----------------------------------------------
    def _build(self) -> None:
        """The NLP over the scaled states (p, v/v_max, a/a_max) at the N+1 nodes and the
        scaled jerks (u/j_max) of the N intervals; parameters: the wrist-centre goal and dt.
        The first node is fixed to ``x0`` through its bounds."""
        import casadi as ca

        s, n = self.settings, self.n_arm
        N = self.N = int(s.intervals)
        nx = 3 * n
        self._sx = np.r_[np.ones(n), self.v_max, self.a_max]  # state scales
        self._su = self.j_max.copy()  # jerk scales
        Xs = ca.SX.sym("X", nx, N + 1)
        Us = ca.SX.sym("U", n, N)
        P = ca.SX.sym("P", 4)  # wc goal (3), dt
        goal, dt = P[:3], P[3]
        X = ca.diag(ca.DM(self._sx)) @ Xs
        U = ca.diag(ca.DM(self._su)) @ Us
        inv_sx = ca.DM(1.0 / self._sx)
        g = []
        for k in range(N):
            p, v, a = X[:n, k], X[n : 2 * n, k], X[2 * n :, k]
            j = U[:, k]
            nxt = ca.vertcat(
                p + dt * (v + dt * (a / 2 + dt * j / 6)),
                v + dt * (a + dt * j / 2),
                a + dt * j,
            )  # exactly solver_base.integrate
            g.append((nxt - X[:, k + 1]) * inv_sx)
        miss = self.reach.casadi(X[:n, N]) - goal
        if self.terminal == "hard":
            g.append(miss)
        effort = s.effort_weight * dt * ca.sumsqr(U)
        terminal = s.terminal_velocity_weight * ca.sumsqr(X[n : 2 * n, N])
        if self.terminal == "soft":
            terminal += s.terminal_position_weight * ca.sumsqr(miss)
        terminal += s.terminal_acceleration_weight * ca.sumsqr(X[2 * n :, N])
        w = ca.vertcat(ca.vec(Xs), ca.vec(Us))
        nlp = {"x": w, "p": P, "f": effort + terminal, "g": ca.vertcat(*g)}
        opts = {
            "print_time": False,
            "error_on_fail": False,
            "ipopt": {
                "max_iter": int(s.max_iter),
                "print_level": 0,
                "sb": "yes",
                "tol": s.tolerance,
                "acceptable_tol": 10 * s.tolerance,
                "acceptable_constr_viol_tol": 1e-4,  # m at the terminal: as constr_viol_tol
            },
        }
        self._solver = ca.nlpsol("mpc", "ipopt", nlp, opts)  # cold: IPOPT's own mu_init
        warm = {**opts, "ipopt": {**opts["ipopt"], "mu_init": s.warm_mu_init}}
        self._solver_warm = ca.nlpsol("mpc_warm", "ipopt", nlp, warm)
        lo = np.r_[self.q_lo, -np.ones(2 * n)]
        hi = np.r_[self.q_hi, np.ones(2 * n)]
        self._lbx = np.r_[np.tile(lo, N + 1), -np.ones(n * N)]
        self._ubx = np.r_[np.tile(hi, N + 1), np.ones(n * N)]

    # -- prediction ----------------------------------------------------------------------
    def predict(self, b: Belief) -> Prediction | None:
        if self.settings.predictor == "fit":
            return self._fit(b)
        c = b.crossing
        if not c.ok:
            return None
        return Prediction(np.array(c.mean[:2], dtype=float), float(b.stamp + c.mean[2]))

    def _fit(self, b: Belief) -> Prediction | None:
        """The design's least-squares fit over the belief positions of the last ``fit_window``
        seconds: x, y linear, z quadratic (gravity free, or fixed with ``fit_gravity``), time
        from the newest stamp; at least :data:`FIT_MIN_SAMPLES` of them."""
        s, w = self.settings, self._window
        stamp = float(b.stamp)
        if w and stamp < w[-1][0]:
            w.clear()  # out of order: another throw
        if w and stamp == w[-1][0]:
            w.pop()  # the same detection's time: the newer belief
        w.append((stamp, np.array(b.mean[:3], dtype=float)))
        while w[0][0] < stamp - s.fit_window - 1e-9:
            w.popleft()
        if len(w) < FIT_MIN_SAMPLES:
            return None
        t = np.array([x[0] for x in w]) - stamp
        pos = np.array([x[1] for x in w])
        lin = np.c_[np.ones_like(t), t]
        (x0, vx), (y0, vy) = (np.linalg.lstsq(lin, pos[:, i], rcond=None)[0] for i in (0, 1))
        if s.fit_gravity:
            z = pos[:, 2] + 0.5 * self.gravity * t * t
            z0, vz = np.linalg.lstsq(lin, z, rcond=None)[0]
            az = -self.gravity
        else:
            z0, vz, az = np.linalg.lstsq(np.c_[lin, 0.5 * t * t], pos[:, 2], rcond=None)[0]
        plane = self.tree.plane_x
        if not vx < -FIT_MIN_SPEED or x0 < plane:
            return None
        tau = (plane - x0) / vx
        yz = np.array([y0 + vy * tau, z0 + vz * tau + 0.5 * az * tau * tau])
        return Prediction(yz, stamp + float(tau))

    # -- the solve -----------------------------------------------------------------------
    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        self._t_now = float(b.t_now)
        return super().decide(b, ep)

    def solve(
        self, x0: np.ndarray, wc_goal: np.ndarray, horizon: float, t0: float | None = None
    ) -> Solution:
        """Jerks from ``x0`` to the wrist centre ``wc_goal`` in ``horizon`` [s]; ``t0``: when
        the plan starts on the plans' clock (for the warm start; default: the decision's)."""
        n, N = self.n_arm, self.N
        t0 = self._t_now if t0 is None else float(t0)
        empty = np.zeros((0, n))
        if not (horizon > 0 and math.isfinite(horizon)):
            return Solution(False, "error", empty, 0.0)
        dt = horizon / N
        x0 = np.asarray(x0, dtype=float)
        guess = self._shifted(x0, t0, dt)
        warm = guess is not None
        if not warm:
            guess = self._cold(x0, dt)
        X, U = guess
        lbx, ubx = self._lbx.copy(), self._ubx.copy()
        lbx[: 3 * n] = ubx[: 3 * n] = x0 / self._sx
        w0 = np.r_[(X / self._sx).ravel(), (U / self._su).ravel()]
        args = dict(x0=w0, p=np.r_[wc_goal, dt], lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0)
        solver = self._solver_warm if warm else self._solver
        try:
            out = solver(**args)
            stats = solver.stats()
        except Exception:  # CasADi raises for a function evaluation gone wrong
            return Solution(False, "error", empty, dt)
        status = str(stats.get("return_status", ""))
        iterations = int(stats.get("iter_count", 0))
        reason = ipopt_reason(status)
        wv = np.asarray(out["x"], dtype=float).ravel()
        nx = 3 * n
        Xs = wv[: nx * (N + 1)].reshape(N + 1, nx) * self._sx
        Us = wv[nx * (N + 1) :].reshape(N, n) * self._su
        if reason or not (np.all(np.isfinite(Us)) and np.all(np.isfinite(Xs))):
            return Solution(False, reason or "error", empty, dt, iterations)
        self._warm = (t0, dt, Xs, Us)
        return Solution(True, "", Us, dt, iterations)

    def _cold(self, x0: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Zero jerk: the state held at ``x0``'s position (states (N+1, 3n), jerks (N, n))."""
        n, N = self.n_arm, self.N
        X = np.tile(np.r_[x0[:n], np.zeros(2 * n)], (N + 1, 1))
        X[0] = x0
        return X, np.zeros((N, n))

    def _shifted(self, x0: np.ndarray, t0: float, dt: float):
        """The last solution evaluated at the new nodes (exact between its nodes; held after
        its end), or None without one that overlaps the new plan's start."""
        if self._warm is None:
            return None
        t_prev, dt_prev, Xp, Up = self._warm
        n, N = self.n_arm, self.N
        Np = len(Up)
        end = Np * dt_prev
        shift = t0 - t_prev
        if not (0.0 <= shift < end):
            return None
        X = np.empty((N + 1, 3 * n))
        U = np.zeros((N, n))
        for k in range(N + 1):
            t = shift + k * dt
            if t >= end:
                X[k] = np.r_[Xp[-1, :n], np.zeros(2 * n)]  # held at its end
                continue
            i = min(int(t / dt_prev), Np - 1)
            X[k] = _propagate(Xp[i], Up[i], t - i * dt_prev, n)
            if k < N:
                i_mid = min(int((t + 0.5 * dt) / dt_prev), Np - 1)
                U[k] = Up[i_mid] if t + 0.5 * dt < end else 0.0
        X[0] = x0
        return X, U

    def reset(self) -> None:
        super().reset()
        self._window.clear()
        self._warm = None


def _propagate(x: np.ndarray, j: np.ndarray, tau: float, n: int) -> np.ndarray:
    """The triple integrator's state ``x`` (3n,) after ``tau`` [s] of the constant jerk ``j``."""
    p, v, a = x[:n], x[n : 2 * n], x[2 * n :]
    return np.r_[
        p + tau * (v + tau * (a / 2 + tau * j / 6)), v + tau * (a + tau * j / 2), a + tau * j
    ]
