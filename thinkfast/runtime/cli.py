"""``thinkfast-run``: the runtime daemon (zenoh in, EGM out). Not built yet: prints its help."""

from __future__ import annotations

import sys

from thinkfast.cli_util import make_app, run_app

app = make_app("thinkfast runtime daemon: ball detections over zenoh in, EGM setpoints out.")


@app.callback(invoke_without_command=True)
def run() -> None:
    """The daemon is not implemented yet (issue 5)."""
    print("thinkfast-run: the daemon is not implemented yet (see --help)", file=sys.stderr)
    sys.exit(1)


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-run", argv))
