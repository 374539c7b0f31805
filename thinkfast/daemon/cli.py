"""``thinkfast-run``: the runtime daemon (zenoh detections in, EGM setpoints out)."""

from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path

import typer

from thinkfast.cli_util import (
    KEY_PREFIX,
    ZENOH_CONFIG,
    ZENOH_CONNECT,
    ZENOH_LISTEN,
    ZenohConfigFile,
    ZenohEndpoints,
    make_app,
    run_app,
)
from thinkfast.control.planners import registry
from thinkfast.link.registry import names as link_names

app = make_app("thinkfast runtime daemon: ball detections over zenoh in, EGM setpoints out.")

# Where the daemon serves EGM. The controller's UDP unicast device sends to this port
# (the kit's sys_cfg_udpuc.cfg, robots/<name>/controller/; tests/test_controller_kit.py keeps
# them equal).
EGM_BIND_DEFAULT = "0.0.0.0:6510"


@app.command()
def run(
    tree: Path | None = typer.Option(None, "--tree", help="compiled action tree (HDF5); required"),
    config: Path | None = typer.Option(None, "--config", help="runtime configuration (TOML)"),
    print_config: bool = typer.Option(
        False, "--print-config", help="print every runtime config default as TOML and exit"
    ),
    check_config: Path | None = typer.Option(
        None,
        "--check-config",
        help="load and validate this runtime config (with --tree: its robot against the "
        "tree's), print OK and exit",
    ),
    planner: str = typer.Option("tree", "--planner", help=registry.describe(online=True)),
    egm_bind: str = typer.Option(EGM_BIND_DEFAULT, "--egm-bind", help="UDP HOST:PORT to serve EGM"),
    egm_controller: str | None = typer.Option(
        None,
        "--egm-controller",
        help="serve only this controller, IP or IP:PORT (default: the first valid sender)",
    ),
    egm_handover: float = typer.Option(
        1.0,
        "--egm-handover",
        help="without --egm-controller: another sender may take over after the served "
        "controller was silent this long (s)",
    ),
    link: str = typer.Option(
        "egm",
        "--link",
        help="the controller link: " + ", ".join(link_names()) + " (docs/ARCHITECTURE.md)",
    ),
    key_prefix: str = KEY_PREFIX,
    zenoh_connect: ZenohEndpoints = ZENOH_CONNECT,
    zenoh_listen: ZenohEndpoints = ZENOH_LISTEN,
    zenoh_config: ZenohConfigFile = ZENOH_CONFIG,
    insecure_zenoh: bool = typer.Option(
        False,
        "--insecure-zenoh",
        help="open a zenoh session that other hosts reach (a non-loopback endpoint, multicast "
        "scouting) without mutual TLS: anyone on the network can move the arm; warns every "
        "minute (docs/SECURITY.md)",
    ),
    record: Path | None = typer.Option(None, "--record", help="flight recorder file (HDF5)"),
    ros_domain: int | None = typer.Option(
        None,
        "--ros-domain",
        help="also speak ROS 2 on this domain (rmw_zenoh layout, docs/ROS2.md): PointStamped "
        "detections in, JointState and DiagnosticArray out; needs the ros extra",
    ),
    log_level: str = typer.Option("info", "--log-level", help="debug, info, warning or error"),
    log_format: str = typer.Option(
        "text", "--log-format", help="text, or json (one JSON object per line, for collectors)"
    ),
    shadow: bool = typer.Option(
        False,
        "--shadow",
        help="first light: plan and publish everything, command the position measured when "
        "the stream starts (the arm does not move; status.shadow shows the plan)",
    ),
    speed_scale: float = typer.Option(
        1.0,
        "--speed-scale",
        help="scale the velocity, acceleration and jerk limits by this (0 < S <= 1; not with "
        "a planner that follows compiled edges at the full limits, tree-rest)",
    ),
    go_home: bool = typer.Option(
        True,
        "--go-home/--hold-away",
        help="arm away from home at start-up: move it home (return speed) once the way is "
        "checked against the cell (a blocked way holds it), or hold it where it stands "
        "(status state fault, balls ignored)",
    ),
    busy_poll: bool = typer.Option(
        False,
        "--busy-poll",
        help="never sleep: spin on the EGM socket (hot CPU for every reply; costs one core)",
    ),
    spin_ahead: float = typer.Option(
        0.0,
        "--spin-ahead-ms",
        help="spin on the EGM socket from this long before each EgmRobot is due (ms; 0 sleeps)",
    ),
    cpu: int | None = typer.Option(
        None, "--cpu", help="run the EGM loop on this CPU, zenoh's threads on the others"
    ),
    fifo: int | None = typer.Option(
        None, "--fifo", help="run the EGM loop under SCHED_FIFO at this priority (1-99)"
    ),
    reply_process: bool = typer.Option(
        False,
        "--reply-process",
        help="answer EGM from a process of its own that planning cannot delay (--cpu and "
        "--fifo apply to it); a planner silent for [safety] planner_timeout brakes the arm",
    ),
    test_stall_planner: str | None = typer.Option(None, "--test-stall-planner", hidden=True),
    foxglove: str | None = typer.Option(
        None,
        "--foxglove",
        help="live view in Foxglove: serve its WebSocket protocol on [HOST:]PORT (loopback by "
        "default; needs the foxglove extra); not with --rerun",
    ),
    rerun: str | None = typer.Option(
        None,
        "--rerun",
        help="live view with Rerun: spawn, connect[=URL] or save=FILE.rrd (docs/LIVE_VIEW.md; "
        "needs the view extra); logged in idle time, never in an EGM reply",
    ),
) -> None:
    """Run until SIGINT/SIGTERM, then brake smoothly and exit 0."""
    if record is not None and tree is not None and not print_config and check_config is None:
        from thinkfast.record.pipe import start_writer_early

        start_writer_early(record)  # the writer's imports beside the ones below
    from thinkfast.contract.zenoh_session import session_config
    from thinkfast.control.config import load_run_config
    from thinkfast.daemon.service import Daemon, Endpoints, Modes
    from thinkfast.errors import ConfigError
    from thinkfast.link.egm_address import parse_controller, parse_hostport
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.robot_match import robot_for_tree

    if print_config or check_config is not None:
        _config_tool(print_config, check_config, tree)
        return
    if tree is None:
        raise typer.BadParameter(
            "missing (required unless --print-config or --check-config)", param_hint="'--tree'"
        )
    try:
        entry = registry.get(planner, online=True)
    except ValueError as e:
        raise ConfigError("--planner", None, str(e)) from None
    if log_level.upper() not in ("DEBUG", "INFO", "WARNING", "ERROR"):
        raise ConfigError("--log-level", None, f"{log_level!r} is not one of debug, info, ...")
    if not 0.0 < speed_scale <= 1.0:
        raise ConfigError("--speed-scale", None, f"{speed_scale} is not in (0, 1]")
    if speed_scale < 1.0 and entry.load().full_limits:
        raise ConfigError(
            "--speed-scale", None, f"not with --planner {planner} (its compiled edges use the "
            "full limits)",
        )  # fmt: skip
    setup_logging(log_level, log_format)
    zenoh_logging(log_format)
    if rerun is not None:
        from thinkfast.view.live import parse_sink

        parse_sink(rerun)
    if foxglove is not None:
        from thinkfast.view.foxglove import foxglove_address as parse_fox

        if rerun is not None:
            raise ConfigError("--foxglove", None, "not with --rerun: one live view at a time")
        fox = parse_fox(foxglove)
    parse_hostport(egm_bind)
    parse_controller(egm_controller)
    if not 0.0 < egm_handover < math.inf:
        raise ConfigError("--egm-handover", None, f"{egm_handover} is not a duration > 0")
    if not 0.0 <= spin_ahead < math.inf:
        raise ConfigError("--spin-ahead-ms", None, f"{spin_ahead} is not a duration >= 0")
    if fifo is not None and busy_poll:
        raise ConfigError(
            "--fifo", None, "not with --busy-poll: the kernel throttles a SCHED_FIFO thread "
            "that never sleeps (use --spin-ahead-ms)",
        )  # fmt: skip
    if entry.load().slow and not reply_process:
        raise ConfigError(
            "--planner", None, f"{planner} solves an optimisation per decision, which can take "
            "longer than an EGM cycle: run it with --reply-process (EGM is then answered by a "
            "process of its own)",
        )  # fmt: skip
    if reply_process and shadow:
        raise ConfigError("--reply-process", None, "not with --shadow")
    if ros_domain is not None:  # one clear error before anything starts
        from thinkfast.contract import ros

        ros.check_options(ros_domain, key_prefix)
    cfg = load_run_config(config)
    if speed_scale < 1.0 and cfg.choice.branches:
        raise ConfigError(
            "--speed-scale", None, "not with [choice] branches = true (compiled edges use the "
            "full limits)",
        )  # fmt: skip
    conf = session_config(  # without a file: no multicast scouting (docs/SECURITY.md)
        connect=zenoh_connect or (),
        listen=zenoh_listen or (),
        config_file=zenoh_config,
        multicast=None if zenoh_config else False,
    )
    t = load_tree(tree)
    robot = robot_for_tree(t.meta, str(tree), cfg.robot)  # the tree's robot, or refused
    refuse_open_zenoh(conf, insecure_zenoh)  # after the config errors, before any socket
    robot = scale_limits(robot, speed_scale)
    ends = Endpoints(
        egm_bind,
        egm_controller,
        egm_handover,
        key_prefix,
        record,
        ros_domain,
        insecure_zenoh,
        link,
    )
    modes = Modes(shadow=shadow, go_home=go_home, speed_scale=speed_scale)
    spin = math.inf if busy_poll else spin_ahead / 1e3
    kind, extra = Daemon, {}
    if reply_process:
        from thinkfast.daemon.planner_process import SplitDaemon

        kind, extra = SplitDaemon, {"stall": _stall_option(test_stall_planner)}
    elif test_stall_planner is not None:
        raise ConfigError("--test-stall-planner", None, "only with --reply-process")
    daemon = kind(
        t, robot, cfg, planner, ends, conf, spin_ahead=spin, cpu=cpu, fifo=fifo, modes=modes,
        **extra,
    )  # fmt: skip
    if rerun is not None:
        from thinkfast.view.live import daemon_view

        daemon.view = daemon_view(rerun, robot, daemon.runtime_tree, cfg)
    if foxglove is not None:
        from thinkfast.view.foxglove import FoxgloveView

        daemon.view = FoxgloveView(*fox, robot, daemon.runtime_tree, cfg)
        logging.getLogger("thinkfast.run").info("foxglove on ws://%s:%d", fox[0], daemon.view.port)
    sys.exit(daemon.run())


def refuse_open_zenoh(conf, insecure: bool) -> None:
    """Refuse a zenoh session that another host reaches without authentication (one line
    naming ``--insecure-zenoh``), unless ``insecure``: then warn once here (and every minute
    after, :class:`~thinkfast.daemon.zenoh_edge.ZenohIO`)."""
    from thinkfast.contract.zenoh_session import session_security
    from thinkfast.errors import ConfigError

    why = session_security(conf).refusal()
    if why is not None and not insecure:
        raise ConfigError("zenoh", None, why)


def _stall_option(text: str | None) -> tuple[float, float] | None:
    """``SECONDS@AFTER`` of the hidden test hook ``--test-stall-planner`` (None: off)."""
    from thinkfast.errors import ConfigError

    if text is None:
        return None
    try:
        seconds, after = (float(x) for x in text.split("@"))
    except ValueError:
        raise ConfigError("--test-stall-planner", None, f"{text!r} is not SECONDS@AFTER") from None
    return seconds, after


def scale_limits(robot, scale: float):
    """``robot`` with its velocity, acceleration and jerk limits scaled by ``scale``."""
    import dataclasses

    if scale == 1.0:
        return robot
    return dataclasses.replace(
        robot, v_max=robot.v_max * scale, a_max=robot.a_max * scale, j_max=robot.j_max * scale
    )


class JsonFormatter(logging.Formatter):
    """One JSON object per record: time, level, logger, message (and the exception)."""

    def format(self, record: logging.LogRecord) -> str:
        out = {
            "time": round(record.created, 6),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        if hasattr(record, "event"):  # daemon events: the same fields, structured
            out["event"], out["detail"] = record.event, record.detail
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out)


def setup_logging(level: str, fmt: str) -> None:
    """Root logging on stderr in ``fmt`` (text or json) at ``level``."""
    from thinkfast.errors import ConfigError

    if fmt not in ("text", "json"):
        raise ConfigError("--log-format", None, f"{fmt!r} is not one of text, json")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(
        JsonFormatter() if fmt == "json"
        else logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s")
    )  # fmt: skip
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())


ZENOH_LOG = "error,zenoh_link_tls=warn"  # zenoh's errors, and the TLS links' refused peers


def zenoh_logging(fmt: str) -> None:
    """zenoh's own log on stderr, in its plain text format: its errors and the TLS handshakes
    it refused (a peer without the cell's certificate, docs/SECURITY.md), or what ``RUST_LOG``
    asks. Under ``--log-format json`` only when ``RUST_LOG`` is set: those lines are not JSON."""
    import os

    if fmt == "json" and "RUST_LOG" not in os.environ:
        return
    os.environ.setdefault("NO_COLOR", "1")  # no terminal colours in a log file or the journal
    import zenoh

    try:
        zenoh.init_log_from_env_or(ZENOH_LOG)
    except Exception:  # already set up in this process (tests run the CLI in-process)
        pass


def _config_tool(print_config: bool, check: Path | None, tree: Path | None = None) -> None:
    """``--print-config``: the defaults as TOML on stdout; ``--check-config FILE``: load and
    validate FILE (and the robot it names; with ``tree``, that robot, or the tree's, checked
    against the tree's), print ``FILE: OK`` (errors raise, naming the key)."""
    from thinkfast.control.config import load_run_config, run_config_toml

    if print_config and check is not None:
        raise typer.BadParameter("not with --check-config", param_hint="'--print-config'")
    if print_config:
        print(run_config_toml(), end="")
        return
    cfg = load_run_config(check)
    if tree is not None:
        from thinkfast.tree.file import load_tree
        from thinkfast.tree.robot_match import robot_for_tree

        robot = robot_for_tree(load_tree(tree).meta, str(tree), cfg.robot)
        print(f"{check}: OK (robot {robot.name}, the one {tree} was compiled for)")
        return
    from thinkfast.robot.model import load_robot

    load_robot(Path(cfg.robot) if cfg.robot else None)  # the robot it names, or the default
    print(f"{check}: OK")  # the contract's line (docs/INTERFACES.md); --tree adds the robot


def main(argv: list[str] | None = None) -> None:
    """Console entry point; ``thinkfast-run status ...`` watches daemons instead
    (:mod:`thinkfast.daemon.status_cli`)."""
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["status"]:
        from thinkfast.daemon.status_cli import main as status_main

        status_main(args[1:])
    sys.exit(run_app(app, "thinkfast-run", argv))
