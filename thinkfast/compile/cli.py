"""``thinkfast-compile``: offline products (goal grid, action tree) and their inspection."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from thinkfast.cli_util import make_app, run_app

app = make_app("Compile and inspect thinkfast goal grids and action trees (offline).")


@app.callback()
def _group() -> None:
    """Compile and inspect thinkfast goal grids and action trees (offline)."""


@app.command()
def goals(
    config: Path = typer.Argument(..., help="compile configuration (TOML)"),
    png: Path | None = typer.Option(None, "--png", help="draw the reachable grid to this PNG"),
) -> None:
    """Solve the IK goal grid on the intercept plane and print it with a summary."""
    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.goals import solve_goal_grid
    from thinkfast.compile.report import goal_png, goal_summary, goal_table
    from thinkfast.robot.kinematics import Kinematics
    from thinkfast.robot.model import load_robot

    loaded = load_compile_config(config)
    robot = load_robot(loaded.robot_path)
    kin = Kinematics(robot)
    grid = solve_goal_grid(robot, loaded.config.goals, loaded.config.plane.distance, kin)
    print(goal_table(grid, robot, kin.shield(robot.home).centre))
    print()
    print(goal_summary(grid))
    if png is not None:
        goal_png(grid, robot, str(png))
        print(f"wrote {png}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-compile", argv))


if __name__ == "__main__":
    main()
