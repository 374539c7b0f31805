"""``thinkfast-sim record``: flight records of thinkfast-run as a summary, a plot, MCAP or in
Rerun; :func:`convert` also serves ``thinkfast-sim replay``."""

from __future__ import annotations

from pathlib import Path

import typer

from thinkfast.sim.cli_options import RERUN_HELP

SCENE_HELP = (
    "with the MCAP: add /thinkfast/scene (foxglove.SceneUpdate, the live --foxglove view's 3D "
    "scene; needs the foxglove extra). rosbags 0.11 cannot open an MCAP with this protobuf "
    "channel: leave it out for rosbags"
)

REPLAY_FOXGLOVE_HELP = (
    "play the record at its pace (--speed) on a Foxglove WebSocket server at [HOST:]PORT, once "
    "a client subscribes (docs/LIVE_VIEW.md; needs the foxglove extra); not with --zenoh-connect"
)


def convert(
    record: Path, rerun: str | None, mcap: Path | None, tree: Path | None, scene: bool = False
) -> None:
    """``--rerun``, ``--mcap`` and ``--scene`` of replay and the record commands."""
    from thinkfast.record.format import read_record

    sink = None
    if rerun is not None:
        from thinkfast.view.live import parse_sink

        sink = parse_sink(rerun)  # before reading: a bad option fails at once
    rec = read_record(record)
    if mcap is not None:
        from thinkfast.record.tables import run_config
        from thinkfast.view.mcap import write_mcap
        from thinkfast.view.replay import record_robot

        cfg = run_config(rec)
        robot = record_robot(rec, cfg, tree)
        extra = _scene(rec, robot, tree) if scene else None
        counts = write_mcap(rec, mcap, robot.joint_names, extra)
        print(f"wrote {sum(counts.values())} messages on {len(counts)} topics to {mcap}")
    if sink is not None:
        from thinkfast.view.record_rerun import record_to_rerun

        counts = record_to_rerun(rec, sink, tree)
        what = ", ".join(f"{n} {k}" for k, n in counts.items())
        print(f"rerun ({sink.kind}{' ' + sink.target if sink.target else ''}): {what}")


def _scene(rec, robot, tree: Path | None) -> tuple:
    """(robot, plane x, goal grid) for the MCAP's scene channel.

    Raises:
        ConfigError: foxglove-sdk is not installed.
    """
    import importlib.util

    from thinkfast.errors import ConfigError
    from thinkfast.view.replay import plane_and_goals

    if importlib.util.find_spec("foxglove") is None:
        raise ConfigError("--scene", None, "needs foxglove-sdk: pip install 'thinkfast[foxglove]'")
    return (robot, *plane_and_goals(rec, tree))


record_app = typer.Typer(
    help="Flight records of thinkfast-run: summary, plot, MCAP, Rerun.",
    no_args_is_help=True,
    rich_markup_mode=None,
)


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
    scene: bool = typer.Option(False, "--scene", help=SCENE_HELP),
    tree: Path | None = typer.Option(None, "--tree", help="with --scene: draw its goal grid"),
) -> None:
    """The record as MCAP with ROS 2 messages (sensor_msgs/JointState, PointStamped, ...)."""
    convert(record, None, output, tree, scene)


@record_app.command("view")
def record_view_cmd(
    record: Path = typer.Argument(..., help="flight record (HDF5)"),
    rerun: str = typer.Option("spawn", "--rerun", help=RERUN_HELP),
    tree: Path | None = typer.Option(None, "--tree", help="draw its goal grid"),
) -> None:
    """The record in the Rerun viewer (the live view's entities, offline)."""
    convert(record, rerun, None, tree)
