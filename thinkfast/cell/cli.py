"""``thinkfast-cell``: the controller's state, and start/stop of the EGM kit, over RWS 1.0."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from thinkfast.cell.client import (
    DEFAULT_PASSWORD,
    DEFAULT_TASK,
    DEFAULT_URL,
    DEFAULT_USER,
    HTTP_TIMEOUT,
)
from thinkfast.cli_util import make_app, run_app

app = make_app(
    "Controller state, and start/stop of the EGM RAPID program of the controller kit, over ABB "
    "Robot Web Services 1.0 (RobotWare 6; RobotWare 7 is not supported, see docs/CELL_RWS.md)."
)

URL = typer.Option(
    DEFAULT_URL,
    "--url",
    help="controller, http://HOST[:PORT]: the default is a RobotStudio virtual controller; a "
    "real IRC5 answers on its WAN port's IP",
)
USER = typer.Option(
    DEFAULT_USER, "--user", help="RWS user (default: ABB's documented default user)"
)
PASSWORD = typer.Option(
    DEFAULT_PASSWORD,
    "--password",
    help="RWS password (default: the documented password of 'Default User'; change it on a "
    "real controller)",
)
TASK = typer.Option(DEFAULT_TASK, "--task", help="RAPID task holding ThinkfastEGM.mod")
TIMEOUT = typer.Option(HTTP_TIMEOUT, "--timeout", help="seconds to wait for each HTTP answer")


@app.callback()
def _group() -> None:
    """Controller state, and start/stop of the EGM RAPID program, over RWS 1.0 (RobotWare 6)."""


def _cell(url: str, user: str, password: str, task: str, timeout: float):
    from thinkfast.cell.client import Cell
    from thinkfast.errors import ConfigError

    if not timeout > 0:
        raise ConfigError("--timeout", None, f"must be > 0 s, got {timeout}")
    return Cell(url, user, password, task=task, timeout=timeout)


@app.command()
def state(
    url: str = URL,
    user: str = USER,
    password: str = PASSWORD,
    task: str = TASK,
    timeout: float = TIMEOUT,
    as_json: bool = typer.Option(False, "--json", help="print one JSON object"),
) -> None:
    """Motors, operation mode, RAPID execution, tasks, speed ratio and the kit's variables."""
    from thinkfast.cell.state import format_state

    snapshot = _cell(url, user, password, task, timeout).read_state()
    if as_json:
        print(json.dumps(snapshot.to_json()))
    else:
        print(format_state(snapshot))


@app.command()
def start(
    url: str = URL,
    user: str = USER,
    password: str = PASSWORD,
    task: str = TASK,
    timeout: float = TIMEOUT,
    resetpp: bool = typer.Option(
        False,
        "--resetpp",
        help="move the program pointer to main first (RAPID must be stopped; the program then "
        "moves home at v100)",
    ),
    wait: float = typer.Option(
        30.0, "--wait", help="seconds to wait for the program (home move) and for the session"
    ),
) -> None:
    """Start RAPID if stopped and request one EGM session (needs auto mode and motors on).

    Waits until the program shows tf_status "waiting" (it clears requests made while it moves
    home), sets tf_start_request, and waits for "session". Start thinkfast-run first.
    """
    cell = _cell(url, user, password, task, timeout)
    print(cell.start(resetpp=resetpp, wait=wait))


@app.command()
def stop(
    url: str = URL,
    user: str = USER,
    password: str = PASSWORD,
    task: str = TASK,
    timeout: float = TIMEOUT,
    halt: bool = typer.Option(
        False, "--halt", help="then stop RAPID execution (also if the session did not end)"
    ),
    wait: float = typer.Option(5.0, "--wait", help="seconds to wait for the session to end"),
) -> None:
    """End the EGM session with the module's ramp-out (tf_stop_request); --halt stops RAPID."""
    cell = _cell(url, user, password, task, timeout)
    print(cell.stop(halt=halt, wait=wait))


@app.command()
def certs(
    directory: Path = typer.Argument(..., help="where the CA, certificates and configs go"),
    camera: list[str] = typer.Option(
        ["base"], "--camera", help="a camera id of the run config (repeatable; default base)"
    ),
    viewer: list[str] = typer.Option(
        [], "--viewer", help="a read-only node (thinkfast-run status, a ROS 2 bridge; repeatable)"
    ),
    daemon_host: list[str] = typer.Option(
        ["127.0.0.1"],
        "--daemon-host",
        help="the workstation's address or name as the nodes reach it (repeatable: every name "
        "goes in the daemon's certificate, the first in the nodes' connect endpoint)",
    ),
    port: int = typer.Option(7447, "--port", help="the daemon's zenoh TLS port"),
    key_prefix: str = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix"),
    install_dir: str | None = typer.Option(
        None,
        "--install-dir",
        help="where the files will be on the nodes (the configs' paths; default: DIRECTORY)",
    ),
    days: int = typer.Option(730, "--days", help="validity of new certificates (days)"),
) -> None:
    """The secured cell's CA, one certificate per zenoh node and each node's zenoh config
    (mutual TLS, access control: docs/SECURITY.md). Existing CA and certificates are kept."""
    from thinkfast.cell.certs import CellNodes, write_cell
    from thinkfast.errors import ConfigError

    if not 0 < port < 65536:
        raise ConfigError("--port", None, f"{port} is not a TCP port")
    if days < 1:
        raise ConfigError("--days", None, f"{days} is not a number of days >= 1")
    nodes = CellNodes(
        cameras=tuple(dict.fromkeys(camera)), viewers=tuple(dict.fromkeys(viewer)),
        daemon_hosts=tuple(daemon_host), port=port, prefix=key_prefix,
        install_dir=install_dir or "",
    )  # fmt: skip
    try:
        written = write_cell(directory, nodes, days)
    except ValueError as e:
        raise ConfigError("thinkfast-cell certs", None, str(e)) from None
    for name in written:
        print(directory / name)
    print(f"daemon: thinkfast-run ... --zenoh-config {directory / 'daemon.json5'}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-cell", argv))


if __name__ == "__main__":
    main()
