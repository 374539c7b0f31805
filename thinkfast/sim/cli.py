"""``thinkfast-sim``: throw simulated balls at the planner, in real time or in lockstep."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import typer

from thinkfast.cli_util import make_app, run_app

app = make_app("Simulated throws, camera and ABB controller for thinkfast.")
PLANNERS = ("tree", "naive", "oracle", "oracle_seen")


@app.callback()
def _group() -> None:
    """Simulated throws, camera and ABB controller for thinkfast."""


def _throws(n: int, seed: int, throw_set: Path | None):
    from thinkfast.sim.throws import ThrowConfig, load_throw_set, sample_throws

    if throw_set is not None:
        ts = load_throw_set(throw_set)
        return ts.throws[:n] if n else ts.throws
    return sample_throws(ThrowConfig(), n, seed)


@app.command()
def throws(
    output: Path = typer.Option(..., "-o", "--output", help="throw-set file to write (JSON)"),
    n: int = typer.Option(500, "--throws", "-n", help="number of throws"),
    seed: int = typer.Option(1, "--seed", help="random seed"),
) -> None:
    """Write a throw set (docs/THROW_SET_FORMAT.md) so any run can be repeated exactly."""
    from thinkfast.sim.throws import ThrowConfig, sample_throws, save_throw_set

    save_throw_set(output, sample_throws(ThrowConfig(), n, seed), ThrowConfig())
    print(f"wrote {n} throws (seed {seed}) to {output}")


@app.command()
def run(
    tree: Path = typer.Option(..., "--tree", help="compiled action tree (HDF5)"),
    n: int = typer.Option(5, "--throws", "-n", help="number of throws"),
    seed: int = typer.Option(1, "--seed", help="throw and camera-noise seed"),
    planner: str = typer.Option("tree", "--planner", help="tree or naive"),
    throw_set: Path | None = typer.Option(None, "--throw-set", help="throws from this file"),
    egm: str | None = typer.Option(None, "--egm", help="HOST:PORT of a running daemon's EGM"),
    zenoh_endpoint: str | None = typer.Option(None, "--zenoh", help="its zenoh endpoint"),
    key_prefix: str = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix"),
    record: Path | None = typer.Option(None, "--record", help="daemon flight record (HDF5)"),
    config: Path | None = typer.Option(None, "--config", help="daemon runtime config (TOML)"),
    frames: bool = typer.Option(
        False, "--frames", help="publish rendered camera frames to a thinkfast-detect process"
    ),
    frames_resolution: str = typer.Option(
        "hd720", "--frames-resolution", help="hd720 or vga (with --frames)"
    ),
    detect_config: Path | None = typer.Option(
        None, "--detect-config", help="thinkfast-detect config (TOML, with --frames)"
    ),
) -> None:
    """Real time, end to end: daemon process, EGM over UDP, detections over zenoh.

    With --frames the simulator renders the ZED's left and XYZ images of every frame instead
    (docs/CAMERA_FRAMES.md) and a thinkfast-detect process turns them into detections.
    """
    from thinkfast.errors import ConfigError
    from thinkfast.robot.model import load_robot
    from thinkfast.runtime.config import load_run_config
    from thinkfast.runtime.egm_server import parse_hostport
    from thinkfast.sim.realtime import run_throws, run_with_daemon

    if planner not in ("tree", "naive"):
        raise ConfigError("--planner", None, f"{planner!r} is not one of tree, naive")
    if frames_resolution not in ("hd720", "vga"):
        raise ConfigError("--frames-resolution", None, f"{frames_resolution!r}: hd720 or vga")
    if frames and detect_config is not None:
        from thinkfast.perception.config import load_detect_config

        load_detect_config(detect_config)  # fail here, with the key, not in the child
    import logging

    logging.getLogger("thinkfast.sim.controller").setLevel(logging.ERROR)  # overrun chatter
    cfg = load_run_config(config)
    robot = load_robot()
    balls = _throws(n, seed, throw_set)
    via = f", camera frames ({frames_resolution}) via thinkfast-detect" if frames else ""
    print(f"{len(balls)} throws at the {planner} planner (real time, seed {seed}{via})")
    if egm is not None or zenoh_endpoint is not None:
        if egm is None or zenoh_endpoint is None:
            raise ConfigError("--egm/--zenoh", None, "give both to use a running daemon")
        hostport = parse_hostport(egm, "--egm")
        pipeline = None
        if frames:
            from thinkfast.sim.frame_stream import FramePipeline

            pipeline = FramePipeline(
                key_prefix, zenoh_endpoint, frames_resolution, seed, detect_config
            )
        try:
            res = run_throws(
                robot, balls, hostport, zenoh_endpoint, key_prefix, seed, cfg.camera,
                frames=pipeline.stream if pipeline else None,
            )  # fmt: skip
        finally:
            if pipeline is not None:
                print(f"thinkfast-detect: {pipeline.close()}")
    else:
        res = run_with_daemon(
            tree, planner, robot, balls, seed, cfg.camera, key_prefix, record, config,
            frames=frames_resolution if frames else None, detect_config=detect_config,
        )  # fmt: skip
    k = sum(r.blocked for r in res)
    print(f"{planner}: blocked {k} / {len(res)} ({100 * k / max(len(res), 1):.0f} %)")


@app.command()
def bench(
    tree: Path = typer.Option(..., "--tree", help="compiled action tree (HDF5)"),
    n: int = typer.Option(500, "--throws", "-n", help="throws per planner"),
    seed: int = typer.Option(1, "--seed", help="throw and camera-noise seed"),
    planners: str = typer.Option("tree,naive,oracle", "--planners", help="comma separated"),
    throw_set: Path | None = typer.Option(None, "--throw-set", help="throws from this file"),
    jobs: int = typer.Option(0, "--jobs", "-j", help="processes (0: all cores)"),
    config: Path | None = typer.Option(None, "--config", help="runtime config (TOML)"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object"),
    png: Path | None = typer.Option(None, "--png", help="plot success by flight time"),
) -> None:
    """Lockstep statistics: the daemon's kernels in simulated time, every planner, same throws."""
    from thinkfast.compile.grow import default_jobs
    from thinkfast.compile.treefile import load_tree
    from thinkfast.errors import ConfigError
    from thinkfast.runtime.config import load_run_config
    from thinkfast.sim.bench import format_summary, plot_summary, run_bench, summarize

    names = [p.strip() for p in planners.split(",") if p.strip()]
    bad = [p for p in names if p not in PLANNERS]
    if bad or not names:
        raise ConfigError("--planners", None, f"{bad or names} not in {', '.join(PLANNERS)}")
    cfg = load_run_config(config)
    load_tree(tree)  # fail here, with the file's name, not in a worker
    balls = _throws(n, seed, throw_set)
    start = time.perf_counter()
    out = run_bench(
        _WorldFactory(tree, cfg),
        balls,
        names,
        seed,
        jobs or default_jobs(),
        None if as_json else _progress,
    )
    summary = summarize(out, names)
    summary["seconds"] = round(time.perf_counter() - start, 1)
    summary["seed"] = seed
    if as_json:
        print(json.dumps(summary))
    else:
        print(format_summary(summary))
        print(f"({summary['seconds']} s)")
    if png is not None:
        plot_summary(summary, str(png))


class _WorldFactory:
    """Picklable builder of the lockstep world (one per worker process)."""

    def __init__(self, tree: Path, cfg):
        self.tree, self.cfg = tree, cfg

    def __call__(self):
        from thinkfast.compile.treefile import load_tree
        from thinkfast.robot.model import load_robot
        from thinkfast.sim.camera import CameraModelConfig
        from thinkfast.sim.controller import ServoConfig
        from thinkfast.sim.lockstep import World

        return World(
            load_tree(self.tree), load_robot(), self.cfg, ServoConfig(), CameraModelConfig()
        )


def _progress(done: int, total: int) -> None:
    if done == total or done % 25 == 0:
        print(f"  {done}/{total} throws", file=sys.stderr, flush=True)


@app.command()
def replay(
    record: Path = typer.Argument(..., help="flight record of thinkfast-run (HDF5)"),
    zenoh_connect: list[str] | None = typer.Option(None, "--zenoh-connect", help="endpoint"),
    key_prefix: str = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix"),
    speed: float = typer.Option(1.0, "--speed", help="replay speed factor"),
) -> None:
    """Re-publish a flight record's detections (raw payloads) with their original timing
    (schema 1 and 2 records, also a partial one)."""
    from thinkfast.errors import ConfigError
    from thinkfast.runtime.record_format import read_detections
    from thinkfast.sim.publisher import open_session

    t, payloads = read_detections(record)  # RecordFileError: one line naming the file
    if speed <= 0:
        raise ConfigError("--speed", None, "must be > 0")
    session = open_session(connect=list(zenoh_connect or ()))
    pub = session.declare_publisher(f"{key_prefix}/detections")
    time.sleep(0.5)
    start = time.time()
    for ti, p in zip(t - (t[0] if len(t) else 0.0), payloads, strict=True):
        time.sleep(max(0.0, start + ti / speed - time.time()))
        pub.put(p)
    session.close()
    print(f"replayed {len(payloads)} detections from {record}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-sim", argv))
