"""Settings of the optimisation planners, ``[mpc]`` and ``[jpl]`` of the runtime config
(docs/RESULTS.md, "The other interceptors"). Defaults are the published designs' where they give
one (marked DESIGN), else ASSUMED."""

from __future__ import annotations

from dataclasses import dataclass

from thinkfast.config import spec


@dataclass(frozen=True)
class MpcConfig:
    """``mpc``: the fixed-time MPC interceptor (CasADi + IPOPT)."""

    intervals: int = spec(20, lo=4, hi=28, doc="DESIGN: control intervals over the horizon")
    rate: float = spec(20.0, unit="Hz", lo=1.0, hi=250.0, doc="DESIGN: re-solves per second")
    freeze: float = spec(
        0.1,
        unit="s",
        lo=0.0,
        doc="DESIGN: with less time than this to the crossing the last plan plays out open loop",
    )
    deadline: float = spec(
        0.05,
        unit="s",
        lo=0.0,
        lo_open=True,
        doc="DESIGN (one re-solve period): a solve that takes longer is dropped online (the "
        "previous plan kept) and counted; counted only in lockstep",
    )
    max_iter: int = spec(100, lo=1, doc="ASSUMED: IPOPT iterations before a solve fails")
    terminal: str = spec(
        "hard",
        choices=("hard", "soft"),
        doc="DESIGN (hard): the wrist centre at the predicted crossing is a constraint, so an "
        "unreachable crossing is a failed solve and the arm keeps its plan; soft (the planner "
        "mpc-soft, not the design's): a penalty, so the arm goes as near as it can in time",
    )
    terminal_position_weight: float = spec(
        1e4,
        unit="1/m^2",
        lo=0.0,
        lo_open=True,
        doc="ASSUMED: with terminal = soft, the weight of the squared wrist-centre miss",
    )
    terminal_velocity_weight: float = spec(
        10.0, lo=0.0, doc="DESIGN: weight of the squared joint speed at the crossing"
    )
    effort_weight: float = spec(
        0.001, lo=0.0, lo_open=True, doc="ASSUMED: weight of the squared jerk (the effort)"
    )
    terminal_acceleration_weight: float = spec(
        0.0,
        lo=0.0,
        doc="ASSUMED: weight of the squared joint acceleration at the crossing (not the "
        "design's: 0 leaves it out)",
    )
    tolerance: float = spec(
        1e-6, lo=0.0, lo_open=True, doc="ASSUMED: IPOPT's convergence tolerance (tol)"
    )
    warm_mu_init: float = spec(
        1e-3,
        lo=0.0,
        lo_open=True,
        doc="ASSUMED: IPOPT's initial barrier parameter from a warm start (a cold start keeps "
        "IPOPT's 0.1): a start near the solution needs less of the barrier",
    )
    predictor: str = spec(
        "filter",
        choices=("filter", "fit"),
        doc="where the crossing comes from: the project's filter (delta method), or the "
        "design's own least-squares fit (x, y linear, z quadratic) over the recent estimates",
    )
    fit_window: float = spec(
        0.15, unit="s", lo=0.0, lo_open=True, doc="DESIGN: the fit's observation window"
    )
    fit_gravity: bool = spec(
        False,
        doc="the fit's z quadratic with its curvature fixed at the filter's gravity (False: "
        "free, as the design fits it)",
    )


@dataclass(frozen=True)
class JplConfig:
    """``jpl``: EKF estimates, a cubic-polynomial predictor, a receding-horizon sequential
    convex program (OSQP)."""

    predictor: str = spec(
        "cubic",
        choices=("cubic", "filter"),
        doc="where the crossing comes from: the design's cubic polynomials over the last "
        "``window`` estimates, or the project's filter (delta method; for comparison)",
    )
    window: int = spec(
        10, lo=4, hi=200, doc="ASSUMED: L, the filter estimates the cubic polynomials are fit to"
    )
    time_base: str = spec(
        "latest",
        choices=("latest", "first"),
        doc="the fit's time origin: the latest estimate's stamp (well conditioned as the "
        "window slides), or the window's first",
    )
    intervals: int = spec(20, lo=4, hi=28, doc="ASSUMED: control intervals over the horizon")
    scp_iterations: int = spec(
        8, lo=1, hi=100, doc="ASSUMED: QPs per solve at most (then it is counted failed)"
    )
    scp_tolerance: float = spec(
        1e-3,
        unit="m",
        lo=0.0,
        lo_open=True,
        doc="ASSUMED: the SCP stops when the terminal wrist-centre point moves less than this",
    )
    deadline: float = spec(
        0.02,
        unit="s",
        lo=0.0,
        lo_open=True,
        doc="ASSUMED (one estimate at 50 Hz): a solve that takes longer is dropped online (the "
        "previous plan kept) and counted; counted only in lockstep",
    )
    freeze: float = spec(
        0.1,
        unit="s",
        lo=0.0,
        doc="ASSUMED: with less time than this to the crossing the last plan plays out",
    )
    terminal_velocity_weight: float = spec(
        10.0, lo=0.0, doc="ASSUMED: weight of the squared joint speed at the crossing"
    )
    effort_weight: float = spec(
        0.001, lo=0.0, lo_open=True, doc="ASSUMED: weight of the squared jerk (the effort)"
    )
    trust_region: float = spec(
        0.3,
        unit="rad",
        lo=0.0,
        lo_open=True,
        doc="ASSUMED: an SCP iteration moves each joint's angle at the crossing at most this far "
        "from the previous iterate's (where the terminal constraint is linearised)",
    )
