"""Human-readable summaries and plots of compile products (no computation of their own)."""

from __future__ import annotations

from collections import Counter

import numpy as np

from thinkfast.compile.goals import GoalGrid
from thinkfast.compile.inspect import Y_LABEL
from thinkfast.robot.model import Robot


def travel_time(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Joint travel from home as time at top speed: max_j |q_j - home_j| / v_max_j [s].

    Args:
        q: joint angles [rad], shape (..., 6) (NaN rows give NaN).
    """
    return np.max(np.abs(np.asarray(q) - robot.home) / robot.v_max, axis=-1)


def goal_table(grid: GoalGrid, robot: Robot, home_centre: np.ndarray) -> str:
    """The goal grid as a table: travel time from home [s] per reachable point, codes otherwise."""
    ny = len(grid.y)
    t = travel_time(robot, grid.q)
    code = {"out of reach": "R", "joint limit": "L", "collision": "C"}
    y, z = grid.y, grid.z
    hx, hy, hz = home_centre
    lines = [
        f"goal grid: plane x = {grid.plane_distance:.3f} m, y {y[0]:+.2f}..{y[-1]:+.2f} m,"
        f" z {z[0]:.2f}..{z[-1]:.2f} m, {len(y)} x {len(z)} = {len(grid.yz)} points",
        f"home: shield centre ({hx:.3f}, {hy:+.3f}, {hz:.3f}) m, normal +x",
        "cells: joint travel from home as time at top speed [s]; R out of reach, L joint limit,"
        " C collision",
        "",
        "  z \\ y " + "".join(f"{y:+6.2f}" for y in grid.y),
    ]
    for row in range(len(grid.z) - 1, -1, -1):
        cells = []
        for col in range(ny):
            i = row * ny + col
            if grid.reachable[i]:
                cells.append(f"{t[i]:6.2f}")
            else:
                cells.append(f"{code.get(grid.reason[i].split(':')[0], '?'):>6}")
        lines.append(f"  {grid.z[row]:5.2f} " + "".join(cells))
    return "\n".join(lines)


def goal_summary(grid: GoalGrid) -> str:
    """Counts, IK residuals and the reasons for every unreachable point."""
    n, k = len(grid.yz), int(grid.reachable.sum())
    reasons = Counter(r.split(":")[0] for r in grid.reason if r)
    parts = ", ".join(f"{v} {key}" for key, v in sorted(reasons.items())) or "none"
    lines = [f"reachable: {k} / {n} goals; unreachable: {n - k} ({parts})"]
    if k:
        lines.append(
            f"IK residuals (max over goals): position {np.nanmax(grid.position_error):.2e} m,"
            f" normal {np.degrees(np.nanmax(grid.normal_error)):.2e} deg"
        )
    for i in np.flatnonzero(~grid.reachable):
        y, z = grid.yz[i]
        lines.append(f"  unreachable (y {y:+.2f}, z {z:.2f}): {grid.reason[i]}")
    return "\n".join(lines)


def goal_png(grid: GoalGrid, robot: Robot, path: str) -> None:
    """Draw reachable goals coloured by travel time from home; unreachable ones as grey crosses."""
    import matplotlib.pyplot as plt

    fig = goal_figure(grid, robot)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def goal_figure(grid: GoalGrid, robot: Robot):
    """The figure of :func:`goal_png`, laid out like :func:`goal_table`: base y increasing to the
    right and z up, i.e. the plane as the thrower sees it (the robot's left, +y, on the right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = travel_time(robot, grid.q)
    ok = grid.reachable
    fig, ax = plt.subplots(figsize=(7, 6))
    sc = ax.scatter(grid.yz[ok, 0], grid.yz[ok, 1], c=t[ok], cmap="viridis", s=120, marker="s")
    ax.scatter(grid.yz[~ok, 0], grid.yz[~ok, 1], c="0.6", marker="x", s=60, label="unreachable")
    fig.colorbar(sc, ax=ax, label="joint travel from home: max |q - home| / v_max [s]")
    ax.set(xlabel=Y_LABEL, ylabel="base z [m]", aspect="equal")
    ax.set_title(f"IK goals on plane x = {grid.plane_distance:.2f} m ({int(ok.sum())}/{len(ok)})")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), frameon=False)
    fig.tight_layout()
    return fig
