"""``thinkfast-sim``: the simulators' commands (:mod:`thinkfast.sim.cli`) and ``sweep``, a grid of
compile and runtime parameters benched as Dask tasks (docs/SWEEPS.md). The program is put
together here, above the simulators it sweeps.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from thinkfast.sim.cli import app
from thinkfast.sim.cli import main as main  # thinkfast-sim: sim.cli main, with sweep on app
from thinkfast.sim.cli_options import SCHEDULER_HELP


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
    from thinkfast.sweep.report import format_table, plot_sweep, write_results
    from thinkfast.sweep.run import SweepProgress, run_sweep
    from thinkfast.sweep.spec import load_sweep
    from thinkfast.sweep.store import SweepStore

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
