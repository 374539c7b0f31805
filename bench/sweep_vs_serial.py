"""A sweep through Dask against the same points run one after the other with the plain CLIs.

    python bench/sweep_vs_serial.py [SWEEP.toml] [--workers 2] [--out DIR]

Serial: for every distinct tree `thinkfast-compile tree CONFIG -o T.h5 --jobs 1`, then for
every point `thinkfast-sim bench --tree T.h5 ... --jobs 1 --json` (one process at a time).
Sweep: `thinkfast-sim sweep SWEEP.toml --workers N` (an embedded Dask cluster). Prints the wall
time of each, the machine and the load, and checks that every point's summary (all fields but
`seconds`) and every tree's fingerprint are identical. Exit 1 when anything differs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent


def run(argv: list[str]) -> tuple[str, float]:
    """Run a command, return its stdout and wall time; stop the bench if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()[-400:]}")
    return proc.stdout, dt


def without_seconds(summary: dict) -> str:
    return json.dumps({k: v for k, v in summary.items() if k != "seconds"}, sort_keys=True)


def loadavg() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", nargs="?", default=str(ROOT / "bench" / "sweep_4x200.toml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="", help="work directory (default: a temporary one)")
    args = ap.parse_args()

    from thinkfast.config import to_toml
    from thinkfast.sweep.spec import compile_text, load_sweep
    from thinkfast.sweep.store import SweepStore
    from thinkfast.tree.file import load_tree, tree_fingerprint

    spec = load_sweep(args.sweep)
    s = spec.settings
    work = Path(args.out or tempfile.mkdtemp(prefix="sweep_vs_serial_"))
    serial = work / "serial"
    if serial.exists():
        shutil.rmtree(serial)
    serial.mkdir(parents=True)
    loads = [loadavg()]

    # Serial: the plain CLIs, one process at a time.
    t_serial = time.perf_counter()
    trees: dict[str, Path] = {}
    compile_s: list[float] = []
    bench_s: list[float] = []
    serial_out: dict[int, tuple[str, str]] = {}
    for p in spec.points:
        if p.tree_key not in trees:
            cfg = serial / f"{p.tree_key[:12]}.toml"
            cfg.write_text(compile_text(p.compile_config, spec.robot_path))
            h5 = serial / f"{p.tree_key[:12]}.h5"
            _, dt = run([str(BIN / "thinkfast-compile"), "tree", str(cfg), "-o", str(h5),
                         "--jobs", "1"])  # fmt: skip
            compile_s.append(dt)
            trees[p.tree_key] = h5
            loads.append(loadavg())
        run_cfg = serial / f"run_{p.index}.toml"
        run_cfg.write_text(to_toml(p.run_config))
        argv = [str(BIN / "thinkfast-sim"), "bench", "--tree", str(trees[p.tree_key]),
                "--throws", str(s.throws), "--seed", str(s.seed), "--feints", str(s.feints),
                "--planners", ",".join(s.planners), "--jobs", "1", "--json",
                "--config", str(run_cfg)]  # fmt: skip
        if s.mix:
            argv += ["--mix", s.mix]
        if s.reference:
            argv += ["--reference", s.reference]
        out, dt = run(argv)
        bench_s.append(dt)
        loads.append(loadavg())
        fp = tree_fingerprint(load_tree(trees[p.tree_key]))
        serial_out[p.index] = (fp, without_seconds(json.loads(out)))
    t_serial = time.perf_counter() - t_serial

    # The sweep: an embedded Dask cluster.
    sweep_dir = work / "sweep"
    if sweep_dir.exists():
        shutil.rmtree(sweep_dir)
    t_sweep = time.perf_counter()
    run([str(BIN / "thinkfast-sim"), "sweep", args.sweep, "-o", str(sweep_dir),
         "--workers", str(args.workers), "--no-png"])  # fmt: skip
    t_sweep = time.perf_counter() - t_sweep
    loads.append(loadavg())
    doc = json.loads((sweep_dir / "results.json").read_text())
    store = SweepStore(sweep_dir)

    differ = []
    for entry in doc["points"]:
        i = entry["index"]
        fp = tree_fingerprint(load_tree(store.tree_path(entry["tree_key"])))
        if fp != serial_out[i][0]:
            differ.append(f"point {i}: tree fingerprint {fp} vs serial {serial_out[i][0]}")
        if without_seconds(entry["summary"]) != serial_out[i][1]:
            differ.append(f"point {i}: summary differs from the serial bench")

    trees_n, points_n = len(trees), len(spec.points)
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cores, "
          f"Python {platform.python_version()}; load average (1 min) during the runs "
          f"{min(loads):.2f}-{max(loads):.2f}")  # fmt: skip
    print(f"sweep: {args.sweep}: {trees_n} trees, {points_n} points x {s.throws} throws, "
          f"planners {','.join(s.planners)}")  # fmt: skip
    print()
    print("| run | wall time |")
    print("|---|---|")
    print(f"| serial CLIs (compiles {min(compile_s):.0f}-{max(compile_s):.0f} s, benches "
          f"{min(bench_s):.0f}-{max(bench_s):.0f} s) | {t_serial:.0f} s |")  # fmt: skip
    print(f"| sweep, {args.workers} Dask workers | {t_sweep:.0f} s ({t_serial / t_sweep:.2f}x) |")
    print()
    for entry in doc["points"]:
        rates = {k: v["rate"] for k, v in entry["summary"]["planners"].items()}
        print(
            f"point {entry['index']} {entry['params']}: "
            + ", ".join(f"{k} {100 * r:.1f} %" for k, r in rates.items())
        )
    if differ:
        print("\nDIFFERENT:\n" + "\n".join(differ))
        return 1
    print(
        f"\nidentical: {points_n} summaries (all fields but seconds), {trees_n} tree fingerprints"
    )
    print(f"work directory: {work}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
