"""``thinkfast-run status``: watch one or several daemons' status over zenoh in a terminal.

Subscribes to ``<prefix>/status`` of every ``--key-prefix`` (repeatable) on the zenoh network
given by ``--zenoh-connect`` / ``--zenoh-listen`` / ``--zenoh-config`` (as the daemon's
options), and redraws the view (:mod:`thinkfast.daemon.status_view`) ``--rate`` times a second
until Ctrl-C. ``--json`` waits (up to ``--timeout``) for a status of every prefix and a second
one for the rates, prints one JSON object and exits (1 when a prefix was not heard).
"""

from __future__ import annotations

import json
import sys
import time

import typer

from thinkfast.cli_util import (
    ZENOH_CONFIG,
    ZENOH_CONNECT,
    ZENOH_LISTEN,
    ZenohConfigFile,
    ZenohEndpoints,
    make_app,
    run_app,
)

app = make_app("Watch thinkfast daemons' status over zenoh (state, EGM, supervisor, cameras).")


class Listener:
    """Ring-buffered status subscriptions, drained by :meth:`poll` (never in zenoh's thread)."""

    def __init__(self, session, prefixes: list[str], board):
        import zenoh

        from thinkfast.contract import keys

        self.board = board
        self.subs = {
            p: session.declare_subscriber(keys.status(p), zenoh.handlers.RingChannel(8))
            for p in prefixes
        }

    def poll(self) -> int:
        """Take every queued status into the board; returns how many."""
        from thinkfast.contract.zenoh_session import drain

        n = 0
        for prefix, sub in self.subs.items():
            for payload in drain(sub, 8):
                try:
                    status = json.loads(payload)
                except ValueError:
                    continue
                if isinstance(status, dict):
                    self.board.update(prefix, status, time.time())
                    n += 1
        return n


@app.command()
def status(
    key_prefix: list[str] = typer.Option(
        ["thinkfast"], "--key-prefix", help="zenoh key prefix of a daemon (repeatable)"
    ),
    zenoh_connect: ZenohEndpoints = ZENOH_CONNECT,
    zenoh_listen: ZenohEndpoints = ZENOH_LISTEN,
    zenoh_config: ZenohConfigFile = ZENOH_CONFIG,
    as_json: bool = typer.Option(False, "--json", help="print one snapshot as JSON and exit"),
    once: bool = typer.Option(False, "--once", help="draw the view once (after --timeout)"),
    timeout: float = typer.Option(3.0, "--timeout", help="--json/--once: wait this long [s]"),
    rate: float = typer.Option(4.0, "--rate", help="redraws per second"),
) -> None:
    """Show the daemons' status, refreshed live (Ctrl-C ends); --json prints one snapshot."""
    from thinkfast.contract.zenoh_session import open_session, session_config
    from thinkfast.daemon.status_view import StatusBoard
    from thinkfast.errors import ConfigError

    if not 0.1 <= rate <= 50.0 or timeout <= 0.0:
        raise ConfigError("--rate/--timeout", None, "rate within 0.1-50 per second, timeout > 0")
    conf = session_config(
        connect=zenoh_connect or (), listen=zenoh_listen or (), config_file=zenoh_config
    )
    session = open_session(conf)
    board = StatusBoard()
    try:
        listener = Listener(session, list(key_prefix), board)
        if as_json or once:
            _one_shot(listener, board, list(key_prefix), timeout, as_json)
        else:
            _live(listener, board, tuple(key_prefix), rate)
    finally:
        session.close()


def _one_shot(listener, board, prefixes: list[str], timeout: float, as_json: bool) -> None:
    """Wait for two statuses of every prefix (the second gives rates), or ``timeout``."""
    from thinkfast.daemon.status_view import render, snapshot

    deadline = time.time() + timeout
    while time.time() < deadline:
        listener.poll()
        if all(p in board.daemons and board.daemons[p].rates for p in prefixes):
            break
        time.sleep(0.05)
    now = time.time()
    if as_json:
        print(json.dumps(snapshot(board, now), sort_keys=True))
    else:
        from rich.console import Console

        Console().print(render(board, now, tuple(prefixes)))
    missing = [p for p in prefixes if p not in board.daemons]
    if missing:
        print(f"no status from {', '.join(missing)} within {timeout:g} s", file=sys.stderr)
        raise typer.Exit(1)


def _live(listener, board, prefixes: tuple[str, ...], rate: float) -> None:
    """Redraw until Ctrl-C (ends with exit status 0)."""
    from rich.live import Live

    from thinkfast.daemon.status_view import render

    with Live(render(board, time.time(), prefixes), refresh_per_second=rate) as live:
        try:
            while True:
                listener.poll()
                live.update(render(board, time.time(), prefixes))
                time.sleep(1.0 / rate)
        except KeyboardInterrupt:
            pass


def main(argv: list[str] | None = None) -> None:
    """``thinkfast-run status ...`` (dispatched by :func:`thinkfast.daemon.cli.main`)."""
    sys.exit(run_app(app, "thinkfast-run status", argv))
