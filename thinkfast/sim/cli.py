"""``thinkfast-sim``: throw simulated balls at the planner, in real time or in lockstep."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import typer

from thinkfast.cli_util import make_app, run_app
from thinkfast.contract import keys
from thinkfast.sim.bench_cli import WorldFactory as _WorldFactory  # noqa: F401 (bench/ scripts)
from thinkfast.sim.bench_cli import bench as bench_cmd
from thinkfast.sim.cli_options import (
    FEINTS_HELP,
    FOXGLOVE_HELP,
    MIX_HELP,
    RERUN_HELP,
    live_view_args,
    tree_cell,
    with_cameras,  # noqa: F401 (bench/ scripts, tests)
)
from thinkfast.sim.cli_options import load_throws as _throws
from thinkfast.sim.cli_options import throw_config as _throw_config
from thinkfast.sim.irc5_cli import controller as controller_cmd
from thinkfast.sim.planners import check_planners, online_planners
from thinkfast.sim.record_cli import REPLAY_FOXGLOVE_HELP, SCENE_HELP, convert, record_app

app = make_app("Simulated throws, camera and ABB controller for thinkfast.")


@app.callback()
def _group() -> None:
    """Simulated throws, camera and ABB controller for thinkfast."""


@app.command()
def throws(
    output: Path = typer.Option(..., "-o", "--output", help="throw-set file to write (JSON)"),
    n: int = typer.Option(500, "--throws", "-n", help="number of throws"),
    seed: int = typer.Option(1, "--seed", help="random seed"),
    mix: str | None = typer.Option(None, "--mix", help=MIX_HELP),
    feints: int = typer.Option(0, "--feints", help=FEINTS_HELP),
    tree: Path | None = typer.Option(
        None, "--tree", help="aim at this tree's plane (default: the throw model's, 0.8 m)"
    ),
) -> None:
    """Write a throw set (docs/THROW_SET_FORMAT.md) so any run can be repeated exactly."""
    from collections import Counter

    from thinkfast.sim.throwset import save_throw_set

    plane = None
    if tree is not None:
        from thinkfast.sim.cli_options import tree_plane
        from thinkfast.tree.file import load_tree

        plane = tree_plane(load_tree(tree).meta, str(tree))
    balls = _throws(n, seed, None, mix, feints, plane)
    save_throw_set(output, balls, _throw_config(mix, plane))
    kinds = Counter(t.kind for t in balls)
    what = ", ".join(f"{kinds[k]} {k}" for k in ("still", "windup", "feint") if kinds[k])
    print(f"wrote {len(balls)} throws ({what}; seed {seed}) to {output}")


@app.command()
def run(
    tree: Path = typer.Option(..., "--tree", help="compiled action tree (HDF5)"),
    n: int = typer.Option(5, "--throws", "-n", help="number of throws"),
    seed: int = typer.Option(1, "--seed", help="throw and camera-noise seed"),
    planner: str = typer.Option("tree", "--planner", help=", ".join(online_planners())),
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
    foxglove: str | None = typer.Option(None, "--foxglove", help=FOXGLOVE_HELP),
) -> None:
    """Real time, end to end: daemon process, EGM over UDP, detections over zenoh.

    With --frames the simulator renders the ZED's left and XYZ images of every frame instead
    (docs/CAMERA_FRAMES.md) and a thinkfast-detect process turns them into detections.
    --rerun and --foxglove are the daemon's live view (passed on to the daemon it starts).
    """
    from thinkfast.control.config import load_run_config
    from thinkfast.errors import ConfigError
    from thinkfast.link.egm_address import parse_hostport
    from thinkfast.sim.realtime import run_throws, run_with_daemon

    view = live_view_args(rerun, foxglove)  # fail here, not in the daemon
    check_planners([planner], "--planner", None, online=True)
    if frames_resolution not in ("hd720", "vga"):
        raise ConfigError("--frames-resolution", None, f"{frames_resolution!r}: hd720 or vga")
    if frames and detect_config is not None:
        from thinkfast.perception.config import load_detect_config

        load_detect_config(detect_config)  # fail here, with the key, not in the child
    import logging

    logging.getLogger("thinkfast.sim.controller").setLevel(logging.ERROR)  # overrun chatter
    if (egm is None) != (zenoh_endpoint is None):
        raise ConfigError("--egm/--zenoh", None, "give both to use a running daemon")
    if egm is not None and view:
        raise ConfigError(view[0], None, "not with --egm/--zenoh: give it to that daemon")
    cfg = load_run_config(config)
    _, robot, plane = tree_cell(tree, cfg)  # the tree's robot and plane, or refused
    balls = _throws(n, seed, throw_set, mix, feints, plane)
    via = f", camera frames ({frames_resolution}) via thinkfast-detect" if frames else ""
    print(f"{len(balls)} throws at the {planner} planner (real time, seed {seed}{via})")
    if egm is not None or zenoh_endpoint is not None:
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
            daemon_args=view + _slow_planner_args(planner),
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


def _slow_planner_args(planner: str) -> tuple[str, ...]:
    """``--reply-process`` for a planner whose decisions may outlast an EGM cycle (the daemon
    runs it only there), else nothing."""
    from thinkfast.control.planners import registry

    try:
        slow = registry.get(planner, online=True).load().slow
    except ValueError:
        return ()  # the daemon names the valid planners
    if slow:
        print(f"{planner}: the daemon answers EGM from a process of its own (--reply-process)")
    return ("--reply-process",) if slow else ()


app.command("bench")(bench_cmd)  # lockstep statistics, thinkfast/sim/bench_cli.py


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
    foxglove: str | None = typer.Option(None, "--foxglove", help=REPLAY_FOXGLOVE_HELP),
    tree: Path | None = typer.Option(
        None, "--tree", help="with --rerun, --foxglove: draw its goal grid"
    ),
    scene: bool = typer.Option(False, "--scene", help=SCENE_HELP),
) -> None:
    """Re-publish a flight record's detections (raw payloads) with their original timing
    (schema 1 and 2 records, also a partial one).

    With --rerun or --mcap the record is converted instead (docs/LIVE_VIEW.md), and its
    detections are re-published only when --zenoh-connect is given as well. With --foxglove
    the record is drawn live in Foxglove at its own pace.
    """
    from thinkfast.contract.zenoh_session import attributed_put, open_peer
    from thinkfast.errors import ConfigError
    from thinkfast.record.format import read_detections

    if speed <= 0:
        raise ConfigError("--speed", None, "must be > 0")
    if foxglove is not None:
        fox = _foxglove_replay_address(foxglove, zenoh_connect)
    if rerun is not None or mcap is not None:
        convert(record, rerun, mcap, tree, scene)
    if foxglove is not None:
        from thinkfast.record.format import read_record
        from thinkfast.view.foxglove_replay import record_to_foxglove

        record_to_foxglove(read_record(record), *fox, tree, speed)
        return
    if (rerun is not None or mcap is not None) and not zenoh_connect:
        return
    t, payloads = read_detections(record)  # RecordFileError: one line naming the file
    session = open_peer(connect=list(zenoh_connect or ()))
    pub = session.declare_publisher(keys.detections(key_prefix))
    put = attributed_put(pub)
    time.sleep(0.5)
    heard = pub.matching_status.matching
    start = time.time()
    for ti, p in zip(t - (t[0] if len(t) else 0.0), payloads, strict=True):
        time.sleep(max(0.0, start + ti / speed - time.time()))
        put(p)
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


def _foxglove_replay_address(text: str, zenoh_connect) -> tuple[str, int]:
    """``--foxglove`` of replay: (host, port); not with ``--zenoh-connect``."""
    from thinkfast.errors import ConfigError
    from thinkfast.view.foxglove import foxglove_address

    if zenoh_connect:
        raise ConfigError("--foxglove", None, "not with --zenoh-connect: the daemon receiving "
                          "the detections draws them, with its own --foxglove")  # fmt: skip
    return foxglove_address(text)


app.command("controller")(controller_cmd)  # the simulated IRC5 (EGM + RWS), thinkfast/sim/irc5.py
app.add_typer(record_app, name="record")  # thinkfast/sim/record_cli.py
# `thinkfast-sim sweep` runs on the simulators from the layer above: thinkfast/sweep/cli.py adds
# it to this app, and is the program's entry point (pyproject.toml)


def main(argv: list[str] | None = None) -> None:
    """Console entry point (thinkfast-sim's is this one through :mod:`thinkfast.sweep.cli`,
    which adds ``sweep`` to :data:`app` first)."""
    sys.exit(run_app(app, "thinkfast-sim", argv))
