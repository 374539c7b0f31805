"""``jpl``: JPL's general-purpose interception design (Patel et al., "A General Purpose Method
for Robotic Interception of Non-Cooperative Dynamic Targets") on this arm: EKF estimates, a
history-conditioned predictor of independent cubic polynomials, and a receding-horizon
sequential convex program (a QP per iteration, OSQP), re-solved on every new estimate.

The estimate is the project's own filter's belief mean; :meth:`JplPlanner.predict` fits
least-squares cubics to the last ``window`` estimates and takes their first crossing of the
plane; :meth:`JplPlanner.solve` plans joint 1-3 jerks to the crossing ``controller_lag`` early,
the terminal wrist-centre constraint linearised per QP inside a trust region. Units: m, s, rad.

Estimation, prediction, planning, and what differs from the paper and why: docs/DESIGN.md,
"The optimisation planners", "jpl".
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import osqp
import scipy.sparse as sp

from thinkfast.control.config import RunConfig
from thinkfast.control.planners.base import Belief
from thinkfast.control.planners.solver_base import (
    TERMINAL_TOLERANCE,
    Prediction,
    Solution,
    SolverPlanner,
)
from thinkfast.control.timeline import Timeline
from thinkfast.decide.tree_view import RuntimeTree
from thinkfast.robot.model import Robot

DEGREE = 3  # the paper's cubic
OSQP_SETTINGS = dict(
    verbose=False,
    warm_starting=True,
    polishing=True,  # the active set's exact solution: the terminal equality to rounding
    eps_abs=1e-5,
    eps_rel=1e-5,
    max_iter=2000,  # the few QPs that need more are near-degenerate: failed, not waited for
)
_INFEASIBLE = {
    osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE,
    osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE,
    osqp.SolverStatus.OSQP_DUAL_INFEASIBLE,
    osqp.SolverStatus.OSQP_DUAL_INFEASIBLE_INACCURATE,
}
_SOLVED = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
_MAX_ITER = osqp.SolverStatus.OSQP_MAX_ITER_REACHED


def cubic_fit(t: np.ndarray, xyz: np.ndarray, degree: int = DEGREE) -> np.ndarray:
    """Least-squares coefficients (3, degree + 1), highest power first (the paper's
    ``T_ij = t_i^(3-j)``), of independent polynomials through ``xyz`` (L, 3) at times ``t``
    (L,)."""
    T = np.vander(np.asarray(t, dtype=float), degree + 1)
    coef, *_ = np.linalg.lstsq(T, np.asarray(xyz, dtype=float), rcond=None)
    return coef.T


def first_root(coef: np.ndarray, value: float, after: float, until: float) -> float | None:
    """The first t in [after, until] with poly(coef)(t) = value (None: none there)."""
    c = np.array(coef, dtype=float)
    c[-1] -= value
    scale = max(float(np.max(np.abs(c))), 1e-300)
    nz = np.flatnonzero(np.abs(c) > 1e-12 * scale)
    if nz.size == 0 or nz[0] == len(c) - 1:
        return None  # a constant: no root, or all of them
    dc = np.polyder(c)
    best = None
    for r in np.roots(c[nz[0] :]):
        if abs(r.imag) > 1e-6 * (1.0 + abs(r.real)):
            continue
        t = float(r.real)
        for _ in range(2):  # Newton polish: np.roots is an eigenvalue solve
            d = float(np.polyval(dc, t))
            if d == 0.0:
                break
            t -= float(np.polyval(c, t)) / d
        if after - 1e-9 <= t <= until and (best is None or t < best):
            best = t
    return best


class _Dynamics:
    """The exact triple integrator of one joint over ``n`` steps of ``dt`` (as
    :func:`~.solver_base.integrate`): node ``k = 1..n`` states are ``free + G @ u``."""

    def __init__(self, n: int):
        k = np.arange(1, n + 1)[:, None]
        m = (k - np.arange(n)[None, :]).astype(float)  # steps since each jerk began
        self._on = m >= 1
        self._m = m
        self.dt = math.nan

    def set_dt(self, dt: float) -> None:
        if dt == self.dt:
            return
        m, on = self._m, self._on
        self.dt = dt
        self.Gp = np.where(on, dt**3 * (3 * m * m - 3 * m + 1) / 6, 0.0)
        self.Gv = np.where(on, dt**2 * (2 * m - 1) / 2, 0.0)
        self.Ga = np.where(on, dt, 0.0)
        self.t = dt * np.arange(1, m.shape[0] + 1)

    def free(self, p0: float, v0: float, a0: float):
        """(p, v, a) at the nodes under zero jerk, each (n,)."""
        t = self.t
        return p0 + t * (v0 + t * a0 / 2), v0 + t * a0, np.full_like(t, a0)


class _Scp:
    """The QP of one SCP iteration as one OSQP problem of fixed sparsity (module doc).

    Variables ``w = u / j_max`` (n_arm * N, joint-major: the jerks scaled to their limits);
    constraint rows: ``w`` (its box), positions, velocities, accelerations at nodes 1..N (per
    joint, node N's position also within the trust region), the linearised terminal equality
    (3 rows, the one part that changes between iterations)."""

    def __init__(self, n_arm: int, N: int):
        self.n, self.N = n_arm, N
        self.dyn = _Dynamics(N)
        self.nz = nw = n_arm * N
        self.m = 4 * nw + 3
        self.r_term = 4 * nw
        self._A = np.zeros((self.m, nw))
        self._A[np.arange(nw), np.arange(nw)] = 1.0
        self._P = np.zeros((nw, nw))
        lower = np.tril(np.ones((N, N), dtype=bool))
        mA = np.zeros((self.m, nw), dtype=bool)
        mP = np.zeros((nw, nw), dtype=bool)
        mA[np.arange(nw), np.arange(nw)] = True
        for j in range(n_arm):
            c = slice(j * N, (j + 1) * N)
            for blk in range(1, 4):
                mA[blk * nw + j * N : blk * nw + (j + 1) * N, c] = lower
            mP[c, c] = np.triu(np.ones((N, N), dtype=bool))
        mA[self.r_term :, :] = True  # J (3, n) times node N's row: every jerk, every joint
        self._mA, self._mP = mA.T, mP.T  # CSC order: column by column, rows ascending
        self._A_csc = sp.csc_matrix(mA.astype(float))
        self._P_csc = sp.csc_matrix(mP.astype(float))
        self._pN_rows = nw + np.arange(n_arm) * N + (N - 1)  # position rows of node N
        self.solver: osqp.OSQP | None = None

    def load(self, x0, dt, j_max, v_max, a_max, q_lo, q_hi, w_eff, w_vel):
        """The per-solve data: the horizon's ``dt``, the start state ``x0`` (3n,), the limits
        (n,) and the cost's weights."""
        n, N, nw = self.n, self.N, self.nz
        dyn = self.dyn
        dyn.set_dt(dt)
        A, P = self._A, self._P
        P[:] = 0.0
        q = np.zeros(nw)
        lo, hi = np.empty(self.m), np.empty(self.m)
        lo[:nw], hi[:nw] = -1.0, 1.0
        self.free_p = np.empty((n, N))
        g_v = dyn.Gv[-1]
        for j in range(n):
            c = slice(j * N, (j + 1) * N)
            pf, vf, af = dyn.free(x0[j], x0[n + j], x0[2 * n + j])
            self.free_p[j] = pf
            rows = (
                (dyn.Gp, pf, q_lo[j], q_hi[j]),
                (dyn.Gv, vf, -v_max[j], v_max[j]),
                (dyn.Ga, af, -a_max[j], a_max[j]),
            )
            for blk, (G, f, low, high) in enumerate(rows, start=1):
                r = slice(blk * nw + j * N, blk * nw + (j + 1) * N)
                A[r, c] = j_max[j] * G
                lo[r], hi[r] = low - f, high - f
            P[c, c] = 2 * w_vel * j_max[j] ** 2 * np.outer(g_v, g_v)
            P[c, c] += np.diag(np.full(N, 2 * w_eff * dt * j_max[j] ** 2))
            q[c] = 2 * w_vel * j_max[j] * vf[-1] * g_v
        self.j_max, self.q_lo, self.q_hi = j_max, q_lo, q_hi
        self.q, self.lo, self.hi = q, lo, hi
        self.Px = np.triu(P).T[self._mP]

    def set_terminal(self, J, step, p_bar, trust):
        """The linearised terminal equality ``J (q_N - p_bar) = step`` and the trust region
        ``|q_N - p_bar| <= trust`` (within the joint box)."""
        N, g_p = self.N, self.dyn.Gp[-1]
        t = slice(self.r_term, self.r_term + 3)
        for j in range(self.n):
            self._A[t, j * N : (j + 1) * N] = np.outer(J[:, j], self.j_max[j] * g_p)
        pf = self.free_p[:, -1]
        rows = self._pN_rows
        self.lo[rows] = np.maximum(self.q_lo, p_bar - trust) - pf
        self.hi[rows] = np.minimum(self.q_hi, p_bar + trust) - pf
        self.lo[t] = self.hi[t] = step + J @ (p_bar - pf)

    def solve(self):
        Ax = self._A.T[self._mA]
        if self.solver is None:
            self.solver = osqp.OSQP()
            A = sp.csc_matrix((Ax, self._A_csc.indices, self._A_csc.indptr), self._A_csc.shape)
            P = sp.csc_matrix((self.Px, self._P_csc.indices, self._P_csc.indptr), self._P_csc.shape)
            self.solver.setup(P, self.q, A, self.lo, self.hi, **OSQP_SETTINGS)
        else:
            self.solver.update(q=self.q, l=self.lo, u=self.hi, Px=self.Px, Ax=Ax)
        return self.solver.solve(raise_error=False)

    def terminal(self, w: np.ndarray) -> np.ndarray:
        """q_N (n,) of the scaled jerks ``w``."""
        N, g_p = self.N, self.dyn.Gp[-1]
        return self.free_p[:, -1] + self.j_max * (w.reshape(self.n, N) @ g_p)


class JplPlanner(SolverPlanner):
    """The JPL design (module doc). ``last``: the last prediction made (None: none)."""

    def __init__(self, tree: RuntimeTree, robot: Robot, cfg: RunConfig, timeline: Timeline):
        super().__init__(tree, robot, cfg, timeline)
        self.settings = cfg.jpl
        self._window: deque[tuple[float, np.ndarray]] = deque(maxlen=self.settings.window)
        self._scp = _Scp(self.n_arm, self.settings.intervals)
        self._q_last: np.ndarray | None = None  # q_N of the last solution in this throw
        self.last: Prediction | None = None

    # -- prediction ----------------------------------------------------------------------
    def predict(self, b: Belief) -> Prediction | None:
        """The crossing of the cubics fit to the last ``window`` estimates (module doc); with
        ``predictor = "filter"`` the belief's own crossing instead (the window still fills)."""
        w, stamp = self._window, float(b.stamp)
        if not w or stamp > w[-1][0]:
            w.append((stamp, np.array(b.mean[:3], dtype=float)))
        elif stamp == w[-1][0]:
            w[-1] = (stamp, np.array(b.mean[:3], dtype=float))  # that estimate, revised
        # (an estimate older than the latest is not fit: the filter has moved past it)
        self.last = None
        if self.settings.predictor == "filter":
            c = b.crossing
            if c.ok:
                self.last = Prediction(np.array(c.mean[:2], dtype=float), stamp + float(c.mean[2]))
            return self.last
        if len(w) < DEGREE + 1:
            return None  # fewer than the cubic's 4 coefficients: no prediction, the arm waits
        t = np.array([e[0] for e in w])
        origin = t[-1] if self.settings.time_base == "latest" else t[0]
        coef = cubic_fit(t - origin, np.array([e[1] for e in w]))
        now = t[-1] - origin
        if np.polyval(coef[0], now) <= self.tree.plane_x:
            return None  # the fit has the ball at or past the plane already
        tau = first_root(coef[0], self.tree.plane_x, now, now + self.cfg.throw.max_tau)
        if tau is None:
            return None  # the fit turns back before the plane, or crosses too late
        yz = np.array([np.polyval(coef[1], tau), np.polyval(coef[2], tau)])
        self.last = Prediction(yz, float(origin + tau))
        return self.last

    # -- planning ------------------------------------------------------------------------
    def solve(self, x0: np.ndarray, wc_goal: np.ndarray, horizon: float) -> Solution:
        n, s = self.n_arm, self.settings
        N = s.intervals
        qps = 0
        try:
            if not (horizon > 0.0 and np.all(np.isfinite(x0)) and np.all(np.isfinite(wc_goal))):
                return Solution(False, "error", np.zeros((0, n)), 0.0)
            dt = horizon / N
            scp = self._scp
            scp.load(
                np.asarray(x0, dtype=float), dt, self.j_max, self.v_max, self.a_max, self.q_lo,
                self.q_hi, s.effort_weight, s.terminal_velocity_weight,
            )  # fmt: skip
            p_bar = np.clip(self._initial_guess(wc_goal), self.q_lo, self.q_hi)
            wc_bar = self.reach.position(p_bar)
            w = None
            converged = False
            while qps < s.scp_iterations:
                J = self.reach.jacobian(p_bar)
                step = wc_goal - wc_bar
                dq = np.linalg.lstsq(J, step, rcond=None)[0]  # the linearised step's joints
                longest = float(np.max(np.abs(dq)))
                if longest > s.trust_region:  # shortened into the trust region
                    step = step * (s.trust_region / longest)
                scp.set_terminal(J, step, p_bar, s.trust_region * (1 + 1e-6))
                res = scp.solve()
                qps += 1
                status = res.info.status_val
                if status in _INFEASIBLE:
                    return Solution(False, "infeasible", np.zeros((0, n)), dt, qps)
                if status not in _SOLVED or res.x is None or not np.all(np.isfinite(res.x)):
                    # OSQP's own iteration limit counts as the SCP's
                    why = "iterations" if status == _MAX_ITER else "error"
                    return Solution(False, why, np.zeros((0, n)), dt, qps)
                w = np.clip(np.asarray(res.x, dtype=float), -1.0, 1.0)
                p_new = scp.terminal(w)
                wc_new = self.reach.position(p_new)
                moved = float(np.linalg.norm(wc_new - wc_bar))
                p_bar, wc_bar = p_new, wc_new
                if moved < s.scp_tolerance:
                    converged = True
                    break
            jerk = (w.reshape(n, N) * self.j_max[:, None]).T
            if not converged:
                return Solution(False, "iterations", jerk, dt, qps)
            if np.linalg.norm(wc_bar - wc_goal) > TERMINAL_TOLERANCE:
                return Solution(False, "terminal_miss", jerk, dt, qps)  # converged elsewhere
            self._q_last = p_bar.copy()
            return Solution(True, "", jerk, dt, qps)
        except Exception:  # never out of solve: counted as the solver's error
            return Solution(False, "error", np.zeros((0, n)), 0.0, qps)

    def _initial_guess(self, wc_goal: np.ndarray) -> np.ndarray:
        """Where the first QP linearises: the last solution's q_N in this throw, else the joints
        of the compiled goal nearest the point (the tree's IK branch, not another one)."""
        if self._q_last is not None:
            return self._q_last
        point = wc_goal + self.reach.reach * self.normal
        goal = self.tree.nearest_goal(point[1:3])
        return np.array(self.tree.goal_q[goal, : self.n_arm], dtype=float)

    def reset(self) -> None:
        super().reset()
        self._window.clear()
        self._q_last = None
        self.last = None
