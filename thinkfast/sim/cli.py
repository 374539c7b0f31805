"""``thinkfast-sim``: throw simulated balls at the planner, in real time or in lockstep."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import typer

from thinkfast.cli_util import make_app, run_app
from thinkfast.contract import keys
from thinkfast.sim.irc5_cli import controller as controller_cmd

app = make_app("Simulated throws, camera and ABB controller for thinkfast.")
PLANNERS = ("tree", "tree-rest", "naive", "naive-paper", "oracle", "oracle_seen")
PLANNERS += ("tree-hedge-none", "tree-hedge-mean", "tree-hedge-tree")  # lockstep.HEDGED
ONLINE = ("tree", "tree-rest", "naive", "naive-paper")  # the ones the daemon runs


@app.callback()
def _group() -> None:
    """Simulated throws, camera and ABB controller for thinkfast."""


MIX_HELP = (
    "kinds of throw drawn, KIND=WEIGHT,... of still, windup, feint (default: "
    "thinkfast/sim/thrower.py DEFAULT_MIX: half still holds, half wind-ups)"
)
FEINTS_HELP = "feints appended to the drawn throws (ids s<seed>-f<j>)"
SCHEDULER_HELP = (
    "run as Dask tasks (docs/SWEEPS.md): local (an embedded cluster on this machine), serial "
    "(this process, no Dask) or a running scheduler's address, tcp://HOST:8786; same results"
)
RERUN_HELP = (
    "live view with Rerun: spawn, connect[=URL] or save=FILE.rrd (docs/LIVE_VIEW.md; needs the "
    "view extra)"
)


CAMERAS_HELP = (
    "cameras that see the throws, comma separated: base (the run config's [camera]) first, then "
    "ids of its [[cameras]] or side (the default side camera, docs/CAMERAS.md); default: the "
    "run config's. Compare two set-ups by running the same --seed with each"
)


def with_cameras(cfg, cameras: str | None):
    """``cfg`` seeing with the cameras ``cameras`` names (None: unchanged); see CAMERAS_HELP."""
    import dataclasses

    from thinkfast.errors import ConfigError
    from thinkfast.estimate.fusion import DEFAULT_CAMERA, SIDE_CAMERA

    if cameras is None:
        return cfg
    names = [c.strip() for c in cameras.split(",") if c.strip()]
    if not names or names[0] != DEFAULT_CAMERA or len(set(names)) != len(names):
        raise ConfigError("--cameras", None, f"{cameras!r}: base first, each camera once")
    known = {c.id: c for c in cfg.cameras}
    known.setdefault(SIDE_CAMERA.id, SIDE_CAMERA)
    bad = [n for n in names[1:] if n not in known]
    if bad:
        raise ConfigError("--cameras", None, f"{bad[0]!r} is not one of base, {', '.join(known)}")
    return dataclasses.replace(cfg, cameras=tuple(known[n] for n in names[1:]))


def _throw_config(mix: str | None):
    import dataclasses

    from thinkfast.sim.thrower import parse_mix
    from thinkfast.sim.throws import ThrowConfig

    cfg = ThrowConfig()
    if mix is None:
        return cfg
    return dataclasses.replace(cfg, thrower=dataclasses.replace(cfg.thrower, mix=parse_mix(mix)))


def _throws(n: int, seed: int, throw_set: Path | None, mix: str | None = None, feints: int = 0):
    from thinkfast.errors import ConfigError
    from thinkfast.sim.throws import sample_throws
    from thinkfast.sim.throwset import load_throw_set

    if feints < 0:
        raise ConfigError("--feints", None, f"must be >= 0, got {feints}")
    if throw_set is not None:
        if mix is not None or feints:
            raise ConfigError("--mix/--feints", None, "not with --throw-set (the set is given)")
        ts = load_throw_set(throw_set)
        return ts.throws[:n] if n else ts.throws
    return sample_throws(_throw_config(mix), n, seed, feints)


@app.command()
def throws(
    output: Path = typer.Option(..., "-o", "--output", help="throw-set file to write (JSON)"),
    n: int = typer.Option(500, "--throws", "-n", help="number of throws"),
    seed: int = typer.Option(1, "--seed", help="random seed"),
    mix: str | None = typer.Option(None, "--mix", help=MIX_HELP),
    feints: int = typer.Option(0, "--feints", help=FEINTS_HELP),
) -> None:
    """Write a throw set (docs/THROW_SET_FORMAT.md) so any run can be repeated exactly."""
    from collections import Counter

    from thinkfast.sim.throwset import save_throw_set

    balls = _throws(n, seed, None, mix, feints)
    save_throw_set(output, balls, _throw_config(mix))
    kinds = Counter(t.kind for t in balls)
    what = ", ".join(f"{kinds[k]} {k}" for k in ("still", "windup", "feint") if kinds[k])
    print(f"wrote {len(balls)} throws ({what}; seed {seed}) to {output}")


@app.command()
def run(
    tree: Path = typer.Option(..., "--tree", help="compiled action tree (HDF5)"),
    n: int = typer.Option(5, "--throws", "-n", help="number of throws"),
    seed: int = typer.Option(1, "--seed", help="throw and camera-noise seed"),
    planner: str = typer.Option("tree", "--planner", help="tree, tree-rest, naive or naive-paper"),
    throw_set: Path | None = typer.Option(None, "--throw-set", help="throws from this file"),
    mix: str | None = typer.Option(None, "--mix", help=MIX_HELP),
    feints: int = typer.Option(0, "--feints", help=FEINTS_HELP),
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
    rerun: str | None = typer.Option(None, "--rerun", help=RERUN_HELP),
) -> None:
    """Real time, end to end: daemon process, EGM over UDP, detections over zenoh.

    With --frames the simulator renders the ZED's left and XYZ images of every frame instead
    (docs/CAMERA_FRAMES.md) and a thinkfast-detect process turns them into detections.
    """
    from thinkfast.control.config import load_run_config
    from thinkfast.daemon.egm_server import parse_hostport
    from thinkfast.errors import ConfigError
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.realtime import run_throws, run_with_daemon

    if rerun is not None:
        from thinkfast.daemon.live_view import parse_sink

        parse_sink(rerun)  # fail here, not in the daemon
    if planner not in ONLINE:
        raise ConfigError("--planner", None, f"{planner!r} is not one of {', '.join(ONLINE)}")
    if frames_resolution not in ("hd720", "vga"):
        raise ConfigError("--frames-resolution", None, f"{frames_resolution!r}: hd720 or vga")
    if frames and detect_config is not None:
        from thinkfast.perception.config import load_detect_config

        load_detect_config(detect_config)  # fail here, with the key, not in the child
    import logging

    logging.getLogger("thinkfast.sim.controller").setLevel(logging.ERROR)  # overrun chatter
    cfg = load_run_config(config)
    robot = load_robot()
    balls = _throws(n, seed, throw_set, mix, feints)
    via = f", camera frames ({frames_resolution}) via thinkfast-detect" if frames else ""
    print(f"{len(balls)} throws at the {planner} planner (real time, seed {seed}{via})")
    if egm is not None or zenoh_endpoint is not None:
        if egm is None or zenoh_endpoint is None:
            raise ConfigError("--egm/--zenoh", None, "give both to use a running daemon")
        if rerun is not None:
            raise ConfigError("--rerun", None, "not with --egm/--zenoh: give it to that daemon")
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
            daemon_args=() if rerun is None else ("--rerun", rerun),
        )  # fmt: skip
    k = sum(r.blocked for r in res)
    nt = sum(r.kind != "feint" for r in res)
    print(f"{planner}: blocked {k} / {nt} ({100 * k / max(nt, 1):.0f} %)")
    feints = [r for r in res if r.kind == "feint"]
    if feints:
        worst = max(r.displacement for r in feints)
        home = sum(r.home_again for r in feints)
        print(
            f"feints: {len(feints)}, largest shield displacement {worst:.3f} m, home again {home}"
        )


@app.command()
def bench(
    tree: Path = typer.Option(..., "--tree", help="compiled action tree (HDF5)"),
    n: int = typer.Option(500, "--throws", "-n", help="throws per planner"),
    seed: int = typer.Option(1, "--seed", help="throw and camera-noise seed"),
    planners: str = typer.Option(
        "tree,naive,naive-paper,oracle,oracle_seen", "--planners", help="comma separated"
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
    """
    from thinkfast.compile.grow import default_jobs
    from thinkfast.control.config import load_run_config
    from thinkfast.errors import ConfigError
    from thinkfast.sim.bench import format_summary, plot_summary, run_bench, summarize
    from thinkfast.tree.file import load_tree

    names = [p.strip() for p in planners.split(",") if p.strip()]
    bad = [p for p in names if p not in PLANNERS]
    if bad or not names:
        raise ConfigError("--planners", None, f"{bad or names} not in {', '.join(PLANNERS)}")
    if reference is not None and reference not in names:
        raise ConfigError("--reference", None, f"{reference!r} is not one of --planners {names}")
    cfg = with_cameras(load_run_config(config), cameras)
    load_tree(tree)  # fail here, with the file's name, not in a worker
    if feints == -1:
        feints = 0 if throw_set is not None else n // 10
    if chunk < 1:
        raise ConfigError("--chunk", None, f"must be >= 1, got {chunk}")
    balls = _throws(n, seed, throw_set, mix, feints)
    start = time.perf_counter()
    if scheduler is not None:
        from thinkfast.sim.cluster import bench_on_client, open_client

        with open_client(scheduler, jobs or default_jobs()) as client:
            out = bench_on_client(
                client, tree, cfg, balls, names, seed, chunk, None if as_json else _progress
            )
    else:
        out = run_bench(
            _WorldFactory(tree, cfg),
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
        from thinkfast.robot.model import load_robot
        from thinkfast.sim.camera import CameraModelConfig
        from thinkfast.sim.controller import ServoConfig
        from thinkfast.sim.lockstep import World
        from thinkfast.tree.file import load_tree

        return World(
            load_tree(self.tree), load_robot(), self.cfg, ServoConfig(), CameraModelConfig()
        )


def _progress(done: int, total: int) -> None:
    if done == total or done % 25 == 0:
        print(f"  {done}/{total} throws", file=sys.stderr, flush=True)


@app.command()
def sweep(
    sweep_file: Path = typer.Argument(..., help="sweep file (TOML, docs/SWEEPS.md)"),
    output: Path | None = typer.Option(
        None, "-o", "--output", help="results directory (default: ./<sweep file name>-sweep)"
    ),
    scheduler: str = typer.Option("local", "--scheduler", help=SCHEDULER_HELP),
    workers: int = typer.Option(
        0, "--workers", help="workers of the embedded cluster (0: all cores)"
    ),
    png: bool = typer.Option(True, "--png/--no-png", help="plot rate against every swept key"),
    as_json: bool = typer.Option(False, "--json", help="print results.json instead of a table"),
) -> None:
    """Compile and bench a grid of compile and runtime parameters, as Dask tasks.

    Trees are compiled once per distinct config; benches run as chunks of throws. Every
    finished chunk and point is kept in the results directory, so running the same command
    again (after an interruption, or with more values) computes only what is missing. Results:
    results.csv (a row per point and planner), results.json, results.png.
    """
    from thinkfast.compile.grow import default_jobs
    from thinkfast.errors import ConfigError, ThinkfastError
    from thinkfast.sim.cluster import open_client
    from thinkfast.sim.sweep import load_sweep
    from thinkfast.sim.sweep_report import format_table, plot_sweep, write_results
    from thinkfast.sim.sweep_run import SweepProgress, run_sweep
    from thinkfast.sim.sweep_store import SweepStore

    if workers < 0:
        raise ConfigError("--workers", None, f"must be >= 0, got {workers}")
    spec = load_sweep(sweep_file)
    store = SweepStore(output or Path(f"{sweep_file.stem}-sweep"))
    trees = len({p.tree_key for p in spec.points})
    with open_client(scheduler, workers or default_jobs()) as client:
        print(
            f"sweep {sweep_file}: {len(spec.points)} points ({trees} trees) x "
            f"{len(spec.throws)} throws x {len(spec.settings.planners)} planners "
            f"{client.description}; results in {store.root}",
            file=sys.stderr,
            flush=True,
        )
        report = run_sweep(spec, store, client, SweepProgress())
    paths = write_results(spec, store, report.docs)
    if png and report.docs:
        plot_sweep(spec, report.docs, store.root / "results.png")
    if as_json:
        print(paths["json"].read_text(encoding="utf-8"))
    else:
        print(format_table(spec, report.docs))
        print(
            f"\n{report.points_from_disk} points and {report.chunks_from_disk} chunks from disk, "
            f"{report.chunks_computed} chunks computed, {report.trees_compiled} trees compiled "
            f"({report.seconds:.1f} s); {paths['csv']}, {paths['json']}"
            + (f", {store.root / 'results.png'}" if png and report.docs else "")
        )
    if report.failures:
        raise ThinkfastError(
            f"{len(report.failures)} failed: {report.failures[0]}"
            + (f" (and {len(report.failures) - 1} more)" if len(report.failures) > 1 else "")
            + "; finished points are kept, rerun to retry"
        )


@app.command()
def replay(
    record: Path = typer.Argument(..., help="flight record of thinkfast-run (HDF5)"),
    zenoh_connect: list[str] | None = typer.Option(None, "--zenoh-connect", help="endpoint"),
    key_prefix: str = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix"),
    speed: float = typer.Option(1.0, "--speed", help="replay speed factor"),
    rerun: str | None = typer.Option(
        None, "--rerun", help=RERUN_HELP + "; draws the whole record (offline)"
    ),
    mcap: Path | None = typer.Option(
        None, "--mcap", help="write the record as MCAP with ROS 2 messages (Foxglove)"
    ),
    tree: Path | None = typer.Option(None, "--tree", help="with --rerun: draw its goal grid"),
) -> None:
    """Re-publish a flight record's detections (raw payloads) with their original timing
    (schema 1 and 2 records, also a partial one).

    With --rerun or --mcap the record is converted instead (docs/LIVE_VIEW.md), and its
    detections are re-published only when --zenoh-connect is given as well.
    """
    from thinkfast.contract.zenoh_session import open_peer
    from thinkfast.errors import ConfigError
    from thinkfast.record.format import read_detections

    if speed <= 0:
        raise ConfigError("--speed", None, "must be > 0")
    if rerun is not None or mcap is not None:
        _convert(record, rerun, mcap, tree)
        if not zenoh_connect:
            return
    t, payloads = read_detections(record)  # RecordFileError: one line naming the file
    session = open_peer(connect=list(zenoh_connect or ()))
    pub = session.declare_publisher(keys.detections(key_prefix))
    time.sleep(0.5)
    heard = pub.matching_status.matching
    start = time.time()
    for ti, p in zip(t - (t[0] if len(t) else 0.0), payloads, strict=True):
        time.sleep(max(0.0, start + ti / speed - time.time()))
        pub.put(p)
        heard = heard or pub.matching_status.matching
    session.close()
    print(f"replayed {len(payloads)} detections from {record}")
    if not heard:
        print(
            f"thinkfast-sim: warning: no subscriber of {key_prefix}/detections was reachable: "
            "the detections reached no one (start thinkfast-run listening and pass "
            "--zenoh-connect to its endpoint)",
            file=sys.stderr,
        )


def _convert(record: Path, rerun: str | None, mcap: Path | None, tree: Path | None) -> None:
    """``--rerun`` and ``--mcap`` of replay and the record commands."""
    from thinkfast.record.format import read_record

    sink = None
    if rerun is not None:
        from thinkfast.daemon.live_view import parse_sink

        sink = parse_sink(rerun)  # before reading: a bad option fails at once
    rec = read_record(record)
    if mcap is not None:
        from thinkfast.record.mcap import write_mcap
        from thinkfast.record.tables import run_config
        from thinkfast.robot.model import load_robot

        cfg = run_config(rec)
        robot = load_robot(Path(cfg.robot) if cfg.robot else None)
        counts = write_mcap(rec, mcap, robot.joint_names)
        print(f"wrote {sum(counts.values())} messages on {len(counts)} topics to {mcap}")
    if sink is not None:
        from thinkfast.daemon.record_view import record_to_rerun

        counts = record_to_rerun(rec, sink, tree)
        what = ", ".join(f"{n} {k}" for k, n in counts.items())
        print(f"rerun ({sink.kind}{' ' + sink.target if sink.target else ''}): {what}")


record_app = typer.Typer(
    help="Flight records of thinkfast-run: summary, plot, MCAP, Rerun.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(record_app, name="record")
app.command("controller")(controller_cmd)  # the simulated IRC5 (EGM + RWS), thinkfast/sim/irc5.py


@record_app.command("info")
def record_info_cmd(
    record: Path = typer.Argument(..., help="flight record (HDF5)"),
) -> None:
    """Attributes, streams, span, EGM rate and events of a flight record."""
    from thinkfast.record.format import read_record
    from thinkfast.record.plot import record_info

    print("\n".join(record_info(read_record(record))))


@record_app.command("plot")
def record_plot_cmd(
    record: Path = typer.Argument(..., help="flight record (HDF5)"),
    output: Path = typer.Option(..., "-o", "--output", help="PNG to write"),
) -> None:
    """Joints, ball track against the belief, crossing prediction and decisions, as PNG."""
    from thinkfast.record.format import read_record
    from thinkfast.record.plot import plot_record

    plot_record(read_record(record), output)
    print(f"wrote {output}", flush=True)


@record_app.command("mcap")
def record_mcap_cmd(
    record: Path = typer.Argument(..., help="flight record (HDF5)"),
    output: Path = typer.Option(..., "-o", "--output", help="MCAP file to write"),
) -> None:
    """The record as MCAP with ROS 2 messages (sensor_msgs/JointState, PointStamped, ...)."""
    _convert(record, None, output, None)


@record_app.command("view")
def record_view_cmd(
    record: Path = typer.Argument(..., help="flight record (HDF5)"),
    rerun: str = typer.Option("spawn", "--rerun", help=RERUN_HELP),
    tree: Path | None = typer.Option(None, "--tree", help="draw its goal grid"),
) -> None:
    """The record in the Rerun viewer (the live view's entities, offline)."""
    _convert(record, rerun, None, tree)


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-sim", argv))
