"""Shared command-line edge: one clear line on stderr for every error, never a traceback.

Set ``THINKFAST_DEBUG=1`` to see the traceback of an unexpected internal error.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer

from thinkfast.errors import ThinkfastError

# zenoh options shared by every long-running command (docs/INTERFACES.md names them)
KEY_PREFIX = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix")
ZENOH_CONNECT = typer.Option(
    None, "--zenoh-connect", help="zenoh endpoint to connect to (repeatable)"
)
ZENOH_LISTEN = typer.Option(None, "--zenoh-listen", help="zenoh endpoint to listen on (repeatable)")
ZENOH_CONFIG = typer.Option(None, "--zenoh-config", help="zenoh JSON5 config")
ZenohEndpoints = list[str] | None
ZenohConfigFile = Path | None


def make_app(help_text: str) -> typer.Typer:
    """A typer app with plain (non-rich) output, so errors stay one line."""
    return typer.Typer(
        help=help_text,
        add_completion=False,
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        rich_markup_mode=None,
    )


def run_app(app: typer.Typer, prog: str, argv: list[str] | None = None) -> int:
    """Run ``app`` and turn every failure into ``prog: error: ...`` and an exit status.

    ``--version`` anywhere before ``--`` prints ``prog thinkfast VERSION`` and returns 0.

    Returns:
        The exit status (0 success; 1 thinkfast error or a command's own failure; 2 usage error;
        130 interrupted).
    """
    if asks_version(sys.argv[1:] if argv is None else argv):
        from thinkfast import __version__

        print(f"{prog} thinkfast {__version__}")
        return 0
    try:
        result = app(args=argv, prog_name=prog, standalone_mode=False)
    except typer.Exit as exc:
        return int(exc.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        _error(prog, "interrupted")
        return 130
    except ThinkfastError as exc:
        _error(prog, str(exc))
        return 1
    except Exception as exc:
        if hasattr(exc, "format_message") and hasattr(exc, "exit_code"):
            # click's (or typer's vendored click's) usage and parameter errors
            _error(prog, exc.format_message().strip().replace("\n", " "))
            return int(exc.exit_code)
        if os.environ.get("THINKFAST_DEBUG"):  # a bug: still one line unless asked for more
            raise
        _error(prog, f"internal error: {type(exc).__name__}: {exc} (THINKFAST_DEBUG=1 for details)")
        return 1
    return int(result) if isinstance(result, int) else 0


def asks_version(argv: list[str]) -> bool:
    """True when ``--version`` is among the options (before any ``--``), whatever else is there:
    it answers before typer parses, so it works on every command and subcommand."""
    args = list(argv)
    if "--" in args:
        args = args[: args.index("--")]
    return "--version" in args


def _error(prog: str, message: str) -> None:
    print(f"{prog}: error: {message}", file=sys.stderr)
