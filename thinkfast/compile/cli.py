"""``thinkfast-compile``: offline products (goal grid, action tree, controller kit) and their
inspection."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import typer

from thinkfast.cli_util import make_app, run_app

app = make_app("Compile and inspect thinkfast goal grids and action trees (offline).")


@app.callback()
def _group() -> None:
    """Compile and inspect thinkfast goal grids and action trees (offline)."""


class ProgressBar:
    """A one-line progress bar on stderr (a line per phase when stderr is not a terminal)."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self.phase = ""
        self.start = time.perf_counter()
        self.last = 0.0

    def __call__(self, phase: str, done: int, total: int) -> None:
        now = time.perf_counter()
        final = done >= total
        if phase != self.phase:
            self.phase, self.last = phase, 0.0
        if not self.tty and not final:
            return
        if self.tty and not final and now - self.last < 0.1:
            return
        self.last = now
        frac = done / total if total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        line = f"{phase:>10} [{bar}] {done}/{total} ({now - self.start:5.1f} s)"
        end = "\n" if final else ""
        print(("\r" if self.tty else "") + line, end=end, file=sys.stderr, flush=True)


@app.command()
def goals(
    config: Path = typer.Argument(..., help="compile configuration (TOML)"),
    png: Path | None = typer.Option(None, "--png", help="draw the reachable grid to this PNG"),
) -> None:
    """Solve the IK goal grid on the intercept plane and print it with a summary."""
    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.goals import require_reachable, solve_goal_grid
    from thinkfast.compile.home import check_home, placed_robot
    from thinkfast.compile.report import goal_png, goal_summary, goal_table
    from thinkfast.robot.kinematics import Kinematics

    loaded = load_compile_config(config)
    robot = placed_robot(loaded)
    kin = Kinematics(robot)
    grid = solve_goal_grid(robot, loaded.config.goals, loaded.config.plane.distance, kin)
    print(goal_table(grid, robot, kin.shield(robot.home).centre))
    print()
    print(goal_summary(grid))
    if png is not None:
        goal_png(grid, robot, str(png))
        print(f"wrote {png}")
    require_reachable(grid, str(config))
    check_home(robot, loaded.config, str(loaded.path))


@app.command()
def tree(
    config: Path = typer.Argument(..., help="compile configuration (TOML)"),
    output: Path = typer.Option(..., "-o", "--output", help="tree file to write (HDF5)"),
    jobs: int = typer.Option(0, "--jobs", "-j", help="worker processes (0: all cores)"),
    if_changed: bool = typer.Option(
        False, "--if-changed", help="do nothing when OUTPUT was compiled from the same inputs"
    ),
) -> None:
    """Compile the action tree of CONFIG into OUTPUT (identical datasets for any --jobs)."""
    from thinkfast.compile.build import compile_tree
    from thinkfast.compile.config import load_compile_config
    from thinkfast.compile.grow import default_jobs
    from thinkfast.compile.inspect import tree_info
    from thinkfast.errors import ConfigError
    from thinkfast.tree.file import save_tree

    if jobs < 0:
        raise ConfigError("--jobs", None, f"must be >= 0, got {jobs}")
    loaded = load_compile_config(config)
    if if_changed and _up_to_date(output, loaded):
        print(f"{output}: up to date (same config, robot and thinkfast version)")
        return
    tree_ = compile_tree(loaded, jobs=jobs or default_jobs(), progress=ProgressBar())
    save_tree(tree_, output)
    print(tree_info(tree_).split("\n\nparameters")[0])
    print(f"wrote {output} in {tree_.meta['compile_seconds']:.1f} s")


def _up_to_date(output: Path, loaded) -> bool:
    """True when OUTPUT exists, passes every check of its format and checksums, and was compiled
    from the same config, robot and version; a file refused is said so (on stderr) and rebuilt."""
    from thinkfast import __version__
    from thinkfast.errors import ThinkfastError
    from thinkfast.robot.model import load_robot
    from thinkfast.tree.file import load_meta

    if not output.is_file():
        return False
    try:
        meta = load_meta(output)
    except ThinkfastError as exc:
        print(f"thinkfast-compile: compiling again: {exc}", file=sys.stderr)
        return False
    robot = load_robot(loaded.robot_path)
    return (
        meta.get("config_sha256") == loaded.sha256
        and meta.get("urdf_sha256") == robot.urdf_sha256
        and meta.get("robot_toml_sha256") == robot.toml_sha256
        and meta.get("thinkfast_version") == __version__
    )


@app.command()
def info(path: Path = typer.Argument(..., help="tree file (HDF5)")) -> None:
    """Counts per depth, goal coverage, arrival times, parameters and provenance of a tree."""
    from thinkfast.compile.inspect import tree_info
    from thinkfast.tree.file import load_tree

    print(tree_info(load_tree(path)))


@app.command()
def diff(
    a: Path = typer.Argument(..., help="first tree file"),
    b: Path = typer.Argument(..., help="second tree file"),
    png: Path | None = typer.Option(
        None, "--png", help="earliest arrival over the plane: A, B, B-A"
    ),
) -> None:
    """Compare two trees. Exit status 0 when they are the same, 1 when they differ, 2 on trouble."""
    from thinkfast.compile.inspect import diff_png, tree_diff
    from thinkfast.errors import ThinkfastError
    from thinkfast.tree.file import load_tree

    try:
        ta, tb = load_tree(a), load_tree(b)
    except ThinkfastError as exc:
        print(f"thinkfast-compile: error: {exc}", file=sys.stderr)
        raise typer.Exit(2) from None
    result = tree_diff(ta, tb)
    print(result.text)
    if png is not None:
        diff_png(ta, tb, str(png))
        print(f"wrote {png}")
    raise typer.Exit(0 if result.same else 1)


@app.command()
def verify(
    path: Path = typer.Argument(..., help="tree file (HDF5)"),
    jobs: int = typer.Option(0, "--jobs", "-j", help="worker processes (0: all cores)"),
    factor: float = typer.Option(4.0, "--factor", help="re-check this much finer than compiled"),
    robot_path: Path | None = typer.Option(
        None, "--robot", help="robot.toml (default: the one the tree's config names)"
    ),
) -> None:
    """Recompute every edge with Ruckig and re-check limits and collisions; exit 1 on a problem.

    The configuration re-checked against is the tree's resolved ``parameters`` (what the runtime
    reads), not its config text."""
    from thinkfast.compile.config import CompileConfig
    from thinkfast.compile.grow import default_jobs
    from thinkfast.compile.verify import verify_tree
    from thinkfast.config import from_dict
    from thinkfast.robot.model import load_robot
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.provenance import Provenance
    from thinkfast.tree.robot_match import place_for_tree

    tree_ = load_tree(path)
    prov = Provenance.of(tree_.meta, str(path))
    config = from_dict(CompileConfig, prov.config_parameters, f"{path}: attribute parameters")
    if robot_path is None:
        robot_path = (Path(prov.config_path).parent / config.robot).resolve()
    robot = place_for_tree(tree_.meta, load_robot(robot_path), str(path))  # plane and home
    report = verify_tree(tree_, robot, config, factor, jobs or default_jobs(), ProgressBar())
    print(
        f"{path}: {report.edges} tree edges and {report.terminals} terminal edges recomputed, "
        f"{report.checks} collision checks at {factor:g}x resolution, shield paths sampled again"
    )
    for p in report.problems[:20]:
        print(f"  problem: {p}")
    if len(report.problems) > 20:
        print(f"  ... and {len(report.problems) - 20} more")
    print("verify: OK" if report.ok else f"verify: FAILED ({len(report.problems)} problems)")
    raise typer.Exit(0 if report.ok else 1)


@app.command()
def kit(
    robot_toml: Path = typer.Argument(..., help="the robot's robot.toml"),
    output: Path | None = typer.Option(
        None, "-o", "--output", help="directory to write (default: the robot folder's controller/)"
    ),
    check: bool = typer.Option(
        False, "--check", help="write nothing; exit 1 naming each file that differs"
    ),
    tree: Path | None = typer.Option(
        None,
        "--tree",
        help="the cell's tree: its home (a solved one) instead of robot.toml's; the robot must "
        "be the tree's (default output: TREE's name + .controller/ beside it)",
    ),
) -> None:
    """Generate the controller kit (RAPID module, UDP device, Motion config, README) from
    robot.toml: its home in degrees and EGM_MAX_SPEED_DEV (docs/EGM_CONTROLLER.md). A cell
    whose tree solved its own home (docs/ROBOTS.md, "Home") needs the kit of that tree."""
    from thinkfast.compile.kit import (
        capped_joints,
        controller_kit,
        kit_differences,
        max_speed_deviation,
        robot_dir_label,
        write_kit,
    )
    from thinkfast.robot.model import load_robot

    source = None
    if tree is not None:
        from thinkfast.tree.file import load_meta
        from thinkfast.tree.robot_match import robot_for_tree

        robot = robot_for_tree(load_meta(tree), str(tree), robot_toml, placed=False)
        source = f"the home of the tree {tree.name}"
        default = tree.with_suffix(".controller")
    else:
        robot = load_robot(robot_toml)
        default = robot_toml.parent / "controller"
    files = controller_kit(robot, robot_dir_label(robot_toml), source)
    directory = output if output is not None else default
    capped = capped_joints(robot)
    if capped and not check:
        names = ", ".join(robot.joint_names[i] for i in capped)
        print(
            f"note: EGM caps every joint at {max_speed_deviation(robot)} deg/s (the fastest "
            f"positioning joint); {names} may go faster by robot.toml and are held to it "
            "(docs/EGM_CONTROLLER.md, MaxSpeedDeviation)",
            file=sys.stderr,
        )
    if check:
        problems = kit_differences(files, directory)
        for p in problems:
            print(p)
        if problems:
            print(
                f"thinkfast-compile: error: {len(problems)} of {len(files)} kit files differ: run "
                f"thinkfast-compile kit {robot_toml}" + (f" -o {output}" if output else ""),
                file=sys.stderr,
            )
            raise typer.Exit(1)
        print(f"{directory}: up to date ({len(files)} files, {robot.name})")
        return
    for path in write_kit(files, directory):
        print(f"wrote {path}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-compile", argv))


if __name__ == "__main__":
    main()
