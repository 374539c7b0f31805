"""What every scenario shares: the result type, the registry, throws, triggers and the verdict.

A scenario is a function ``fn(ctx, opts) -> Result`` registered with :func:`scenario`. It builds a
:class:`~bench.faultkit.cell.Cell`, injects its faults, and ends with :func:`finish`, which
stops the daemon and applies the common checks (commands, process, latched faults, replies).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from bench.faultkit.cell import Cell, Context
from thinkfast.sim.throws import ThrowConfig, make_throw, sample_throws

MIN_ANSWERED_PCT = 99.0  # replies to the peer's EgmRobot, in percent of its cycles
MAX_UNEXPLAINED_PCT = 0.5  # missed replies no host stall explains, in percent of the cycles


class Result(NamedTuple):
    """One scenario's outcome: ``passed`` None when it could not run (``failures`` says why)."""

    name: str
    passed: bool | None
    figures: dict
    failures: list[str]
    seconds: float


@dataclasses.dataclass(frozen=True)
class Options:
    """Campaign options: throws per long scenario, soak minutes, record, quick (test) mode."""

    throws: int = 50
    soak_minutes: float = 0.0
    record: bool = False
    quick: bool = False


REGISTRY: dict[str, tuple[Callable, str]] = {}


def scenario(name: str, doc: str):
    """Register ``fn(ctx, opts) -> Result`` under ``name`` (one line of ``doc`` for --help)."""

    def deco(fn):
        REGISTRY[name] = (fn, doc)
        return fn

    return deco


# ---------------------------------------------------------------------- throws
def sampled_throws(ctx: Context, n: int, offset: int = 0) -> list:
    """``n`` ordinary throws (the simulator's throw distribution), seeded by the context."""
    return sample_throws(ThrowConfig(), n + offset, ctx.seed)[offset:]


def easy_throw(k: int = 0):
    """A throw any working daemon blocks: 0.75 s of flight to 0.2-0.3 m from home."""
    aims = [(0.25, 1.2), (-0.2, 0.8), (0.15, 0.75), (-0.25, 1.25)]
    return make_throw(ThrowConfig(), np.array([7.6, 0.3, 1.5]), aims[k % 4], 0.75, 0.5,
                      f"easy-{k}")  # fmt: skip


def far_throw(k: int = 0):
    """A throw that moves the arm a long way (0.7 m aside): its command runs away from a frozen
    arm quickly."""
    aims = [(0.75, 0.6), (-0.75, 1.5), (0.75, 1.5), (-0.75, 0.6)]
    return make_throw(ThrowConfig(), np.array([7.6, 0.0, 1.4]), aims[k % 4], 0.8, 0.5,
                      f"far-{k}")  # fmt: skip


def when_moving(cell: Cell, fn: Callable[[], None], threshold: float = 0.05, delay: float = 0.0,
                timeout: float = 2.5) -> Callable[[], None]:  # fmt: skip
    """A hook that waits until the applied command is ``threshold`` [rad] from home on some joint,
    then ``delay`` [s], then calls ``fn`` (nothing when the arm never moves within ``timeout``)."""
    home = cell.ctx.robot.home

    def hook() -> None:
        deadline = time.time() + timeout
        while time.time() < deadline:
            q = cell.ctl.last_cmd
            if q is not None and np.max(np.abs(np.asarray(q) - home)) > threshold:
                time.sleep(delay)
                fn()
                return
            time.sleep(0.004)

    return hook


def blocked_summary(outcomes) -> dict:
    """Blocked and executed counts of a list of throw outcomes."""
    n = len(outcomes)
    b = sum(o.result.blocked for o in outcomes)
    e = sum(o.executed for o in outcomes)
    return {"throws": n, "blocked": b, "block_rate_pct": round(100.0 * b / n, 1) if n else None,
            "executed": e}  # fmt: skip


# ---------------------------------------------------------------------- verdict
_KEEP = ("answered_pct", "cycles", "missed", "missed_host_stall", "missed_unexplained",
         "v_ratio_all", "host_stall_max_ms", "v_ratio", "a_ratio", "a_ratio_all", "speedref_ratio",
         "jerk_ratio_brake", "speedref_jerk_ratio_brake", "jerk_ratio_normal",
         "resyncs_checked", "resyncs_late", "missed_after_silence", "resync_pos_err_mrad",
         "resync_vel_ratio", "gaps", "brake_cycles", "extra_replies", "nonfinite",
         "outside_urdf", "bad_replies", "worst_brake_jerk_modes")  # fmt: skip


def finish(name: str, cell: Cell, t_start: float, figures: dict, failures: list[str], *,
           sig=None, expect_exit0: bool = True, latch_allowed: bool = False,
           replies: bool = True, extra=None, opts=None) -> Result:  # fmt: skip
    """Stop the cell (``sig``: default SIGINT) and apply the common checks; returns the result.

    ``replies``: judge the answered share and unexplained misses (off where faults make missed
    replies legitimate, and in quick mode: a few hundred cycles measure no rate).
    ``latch_allowed``: a latched fault is reported, not failed. ``extra``: ``fn(checker figures)
    -> failures`` of the scenario's own, called before the figures are assembled.
    """
    import signal

    status = cell.status()
    code = cell.stop(sig or signal.SIGINT)
    fig, fails = cell.check()
    failures = list(failures) + fails + cell.process_failures(expect_exit0)
    if extra is not None:  # before the figures are assembled: it may add to ``figures``
        failures += extra(fig)
    latched = cell.monitor.ever_latched()
    if latched and not latch_allowed:
        failures.append("a fault latched")
    figures = {**{k: fig.get(k) for k in _KEEP}, **figures, "exit": code, "latched": latched,
               "load_avg_1min": round(os.getloadavg()[0], 2),
               "controller_rt": getattr(cell, "controller_rt", None)}  # fmt: skip
    for key in (
        "egm",
        "egm_timing",
        "safety",
        "faults",
        "interventions",
        "egm_peer",
        "recorder",
        "detections",
        "throws",
        "state",
    ):
        if key in status:
            figures[f"daemon_{key}"] = status[key]
    if "resync_failures" in fig:
        figures["resync_failures"] = fig["resync_failures"][:5]
    cycles = max(1, fig.get("cycles") or 0)
    if replies and not (opts is not None and opts.quick) and fig.get("answered_pct") is not None:
        if fig["answered_pct"] < MIN_ANSWERED_PCT:
            failures.append(f"answered {fig['answered_pct']:.2f} % < {MIN_ANSWERED_PCT} %")
        if 100.0 * fig["missed_unexplained"] / cycles > MAX_UNEXPLAINED_PCT:
            failures.append(f"{fig['missed_unexplained']} missed replies without a host stall")
    if fig.get("cycles", 0) == 0:
        failures.append("no reply at all")
    return Result(name, not failures, figures, failures, round(time.time() - t_start, 1))


def error_result(name: str, t_start: float, exc: BaseException) -> Result:
    """A scenario that could not run to its end (the harness failed, not necessarily the daemon)."""
    return Result(name, None, {}, [f"{type(exc).__name__}: {exc}"], round(time.time() - t_start, 1))
