"""Parameter sweeps: a grid of compile and runtime parameters, each point a tree compiled once
and benched in lockstep as Dask tasks (docs/SWEEPS.md). spec: the sweep file and its points;
store: results on disk, finished chunks kept; run: the tasks; report: table and plot; cli: the
``thinkfast-sim sweep`` command (and the program's entry point)."""
