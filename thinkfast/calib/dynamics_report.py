"""What a dynamics estimate means for the configs: per-limit verdicts, the report, the patch.

A limit is changed only where the record measured it: the command reached at least
``approach`` times the current limit and the arm achieved less than ``limited_ratio`` times the
command. A record that never asked for the limit (a ``--speed-scale 0.2`` session, ordinary
throws) says nothing about it: the limit is reported "not measured" and kept.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from thinkfast.calib.dynamics import DynamicsEstimate, DynamicsOptions


class LimitVerdict(NamedTuple):
    """One joint's acceleration or jerk limit after a record.

    Attributes:
        key: robot.toml key (``max_acceleration`` or ``max_jerk``).
        joint: joint index (0-5).
        value: the limit to use [rad/s^2 or rad/s^3]: measured, else the current one.
        status: ``measured``, ``followed`` (command near the limit, arm kept up: kept) or
            ``not measured`` (the record never approached the limit: kept).
        reason: the figures behind the status, for a person.
    """

    key: str
    joint: int
    value: float
    status: str
    reason: str


def limit_verdicts(
    est: DynamicsEstimate,
    a_max: np.ndarray,
    j_max: np.ndarray,
    opts: DynamicsOptions = DynamicsOptions(),
) -> list[LimitVerdict]:
    """Acceleration then jerk verdicts of every joint (12) against the current limits."""
    out = []
    for key, limits in (("max_acceleration", a_max), ("max_jerk", j_max)):
        for j, d in enumerate(est.joints):
            got, cmd, limited = (
                (d.accel, d.accel_cmd, d.accel_limited)
                if key == "max_acceleration"
                else (d.jerk, d.jerk_cmd, d.jerk_limited)
            )
            limit = float(limits[j])
            if not np.isfinite(cmd) or cmd < opts.approach * limit:
                why = f"commanded at most {cmd:.1f}, {100 * cmd / limit:.0f} % of the limit"
                if limited:
                    why += f"; the arm reached only {got:.1f} (check the record's timing)"
                out.append(LimitVerdict(key, j, limit, "not measured", why))
            elif limited:
                why = f"commanded {cmd:.1f}, the arm reached {got:.1f}"
                out.append(LimitVerdict(key, j, float(got), "measured", why))
            else:
                why = f"commanded {cmd:.1f} and the arm followed: its limit is at least that"
                out.append(LimitVerdict(key, j, limit, "followed", why))
    return out


def dynamics_report(est: DynamicsEstimate, source: str, verdicts: list[LimitVerdict]) -> str:
    """A person's summary: lag and limits per joint, then each limit's verdict."""
    lines = [
        f"{source}: {est.seconds:.1f} s on the controller's clock at {1e3 * est.dt:.1f} ms, "
        f"{est.segments} motion segments",
        f"controller lag {1e3 * est.lag:.1f} ms (median over segments and joints)",
        f"{est.breaks} timing breaks (commanded steps off their velocities: the plan's clock "
        f"jumped, or the supervisor acted); {est.excluded:.2f} s around them not counted",
        "",
        "joint  lag_ms  segs  accel  accel_cmd  limited   jerk  jerk_cmd  limited",
    ]
    for j, d in enumerate(est.joints, start=1):
        lines.append(
            f"{j:5d}  {1e3 * d.lag:6.1f}  {d.segments:4d}  {d.accel:5.1f}  {d.accel_cmd:9.1f}  "
            f"{'yes' if d.accel_limited else 'no':>7}  {d.jerk:5.0f}  {d.jerk_cmd:8.0f}  "
            f"{'yes' if d.jerk_limited else 'no':>7}"
        )
    lines += [
        "accel [rad/s^2], jerk [rad/s^3]: largest held for 20 ms; 'limited': the arm achieved "
        "less than commanded",
        "",
    ]
    for v in verdicts:
        lines.append(f"{v.key}[{v.joint}] = {v.value:.2f}: {v.status} ({v.reason})")
    changed = [v for v in verdicts if v.status == "measured"]
    if not changed:
        lines.append("no limit measured: robot.toml stays as it is")
    return "\n".join(lines)


def dynamics_patch(est: DynamicsEstimate, source: str, verdicts: list[LimitVerdict],
                   robot_path: str) -> str:  # fmt: skip
    """The patch: a run config (``thinkfast-run --config`` and ``--check-config`` load it) with
    ``[execution] controller_lag``; measured limits follow as comments for robot.toml (they are
    the compiler's, not the run config's: edit robot.toml and recompile the tree)."""
    lines = [
        f"# thinkfast-calib dynamics: run config patch from {source}",
        "# Load it with thinkfast-run --config, or copy its keys into your run config.",
        "[execution]",
        f"controller_lag = {est.lag:.4f}  # s, median over {est.segments} motion segments",
    ]
    changed = [v for v in verdicts if v.status == "measured"]
    if not changed:
        lines.append("# no acceleration or jerk limit was measured: robot.toml unchanged")
        return "\n".join(lines) + "\n"
    lines += ["", f"# Measured limits: edit {robot_path}, then recompile (thinkfast-compile tree)"]
    for key in ("max_acceleration", "max_jerk"):
        vs = [v for v in verdicts if v.key == key]
        if any(v.status == "measured" for v in vs):
            lines.append(f"#   per joint: {', '.join(v.status for v in vs)}")
            lines.append(f"#   {key} = [{', '.join(f'{v.value:.2f}' for v in vs)}]")
    return "\n".join(lines) + "\n"
