"""``thinkfast-sim bench``: lockstep statistics of every planner on the same throws
(:mod:`thinkfast.sim.bench`)."""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import typer

from thinkfast.sim.cli_options import (
    CAMERAS_HELP,
    FEINTS_HELP,
    MIX_HELP,
    SCHEDULER_HELP,
    load_throws,
    tree_cell,
    with_cameras,
)
from thinkfast.sim.planners import DEFAULT, check_planners, lockstep_planners

# the bench JSON's keys that say where its numbers came from (the rest are the statistics)
PROVENANCE = ("tree_fingerprint", "cell", "machine", "versions")  # where, not what


def bench(
    tree: Path = typer.Option(..., "--tree", help="compiled action tree (HDF5)"),
    n: int = typer.Option(500, "--throws", "-n", help="throws per planner"),
    seed: int = typer.Option(1, "--seed", help="throw and camera-noise seed"),
    planners: str = typer.Option(
        ",".join(DEFAULT),
        "--planners",
        help="comma separated, of " + ", ".join(lockstep_planners()),
    ),
    reference: str | None = typer.Option(
        None,
        "--reference",
        help="planner every other one is compared with, paired (default: tree, or the first "
        "planner when tree does not run)",
    ),
    throw_set: Path | None = typer.Option(None, "--throw-set", help="throws from this file"),
    mix: str | None = typer.Option(None, "--mix", help=MIX_HELP),
    feints: int = typer.Option(
        -1, "--feints", help=FEINTS_HELP + "; default: a tenth of --throws (none with --throw-set)"
    ),
    jobs: int = typer.Option(
        0, "--jobs", "-j", help="processes (0: all cores); with --scheduler local: Dask workers"
    ),
    config: Path | None = typer.Option(None, "--config", help="runtime config (TOML)"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object"),
    png: Path | None = typer.Option(None, "--png", help="plot success by flight time"),
    scheduler: str | None = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
    chunk: int = typer.Option(25, "--chunk", help="throws per task (with --scheduler)"),
    cameras: str | None = typer.Option(None, "--cameras", help=CAMERAS_HELP),
) -> None:
    """Lockstep statistics: the daemon's kernels in simulated time, every planner, same throws.

    Each kind of throw (--mix, --feints) is also reported on its own; feints by how far the
    shield left home and whether it was home again within 2 s. Every planner is compared with
    the --reference planner on the same throws: counts of throws both / only one / neither
    blocked, the difference in rate with a 95 % interval (Newcombe) and an exact McNemar p.
    The JSON also says where the numbers came from (:data:`PROVENANCE`): the tree's
    fingerprint, the machine and the library versions.
    """
    from thinkfast.compile.grow import default_jobs
    from thinkfast.control.config import load_run_config
    from thinkfast.errors import ConfigError
    from thinkfast.machine import library_versions, machine_info
    from thinkfast.sim.bench import format_summary, plot_summary, run_bench, summarize
    from thinkfast.tree.file import tree_fingerprint

    names = [p.strip() for p in planners.split(",") if p.strip()]
    check_planners(names, "--planners", None)
    if reference is not None and reference not in names:
        raise ConfigError("--reference", None, f"{reference!r} is not one of --planners {names}")
    cfg = with_cameras(load_run_config(config), cameras)
    t, robot, plane = tree_cell(tree, cfg)  # fail here, with the file's name
    fingerprint = tree_fingerprint(t)
    if feints == -1:
        feints = 0 if throw_set is not None else n // 10
    if chunk < 1:
        raise ConfigError("--chunk", None, f"must be >= 1, got {chunk}")
    balls = load_throws(n, seed, throw_set, mix, feints, plane)
    start = time.perf_counter()
    if scheduler is not None:
        from thinkfast.sim.cluster import bench_on_client, open_client

        with open_client(scheduler, jobs or default_jobs()) as client:
            out = bench_on_client(
                client, tree, cfg, balls, names, seed, chunk, None if as_json else _progress,
                robot=robot,
            )  # fmt: skip
    else:
        out = run_bench(
            WorldFactory(tree, cfg),
            balls,
            names,
            seed,
            jobs or default_jobs(),
            None if as_json else _progress,
        )
    summary = summarize(out, names, reference)
    summary["seconds"] = round(time.perf_counter() - start, 1)
    summary["seed"] = seed
    if cameras is not None:
        summary["cameras"] = ["base", *(c.id for c in cfg.cameras)]
    summary["tree_fingerprint"] = fingerprint  # PROVENANCE: where the numbers came from
    summary["cell"] = cell_summary(robot, plane)  # the robot and plane that judged them
    summary["machine"] = machine_info()
    summary["versions"] = library_versions()
    if as_json:
        print(json.dumps(summary))
    else:
        print(cell_line(summary["cell"]))
        print(format_summary(summary))
        print(f"({summary['seconds']} s)")
    if png is not None:
        plot_summary(summary, str(png))


class WorldFactory:
    """Picklable builder of the lockstep world (one per worker process), with the tree's robot
    (:func:`~thinkfast.tree.robot_match.robot_for_tree`: the run config's must be the same)."""

    def __init__(self, tree: Path, cfg):
        self.tree, self.cfg = tree, cfg

    def __call__(self):
        from thinkfast.sim.camera import CameraModelConfig
        from thinkfast.sim.controller import ServoConfig
        from thinkfast.sim.lockstep import World
        from thinkfast.tree.file import load_tree
        from thinkfast.tree.robot_match import robot_for_tree

        tree = load_tree(self.tree)
        robot = robot_for_tree(tree.meta, str(self.tree), self.cfg.robot)
        return World(tree, robot, self.cfg, ServoConfig(), CameraModelConfig())


def _progress(done: int, total: int) -> None:
    if done == total or done % 25 == 0:
        print(f"  {done}/{total} throws", file=sys.stderr, flush=True)


def cell_summary(robot, plane) -> dict:
    """The cell a bench was flown and judged in, for its JSON: the robot (name, robot.toml and
    URDF hashes, the home), the plane's pose in ``base`` and the region the throws aimed at."""
    pose = robot.placement
    return {
        "robot": robot.name,
        "robot_toml_sha256": robot.toml_sha256,
        "urdf_sha256": robot.urdf_sha256,
        "home": [float(x) for x in robot.home],
        "plane": pose.as_dict() if pose is not None else {"distance": float(plane.plane_x)},
        "region": {"y": list(plane.aim_y or ()), "z": list(plane.aim_z or ())},
    }


def cell_line(cell: dict) -> str:
    """One line naming the bench's cell (:func:`cell_summary`)."""
    p, r = cell["plane"], cell["region"]
    pose = f", yaw {p['yaw']:g} rad ({math.degrees(p['yaw']):.1f} deg)" if p.get("yaw") else ""
    pose += "".join(f", {k} {p[k]:g} m" for k in ("offset", "base_height") if p.get(k))
    region = f"y {r['y'][0]:g}..{r['y'][1]:g}, z {r['z'][0]:g}..{r['z'][1]:g} m" if r["y"] else ""
    return f"cell: {cell['robot']}, plane x {p['distance']:g} m{pose}; region {region}"
