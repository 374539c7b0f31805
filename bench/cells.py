"""Every cell of trees/: compile, verify and bench each one with the plain CLIs, as a user would.

    python bench/cells.py [--throws 300] [--seed 1] [--out DIR] [--jobs 2] [CONFIG.toml ...]

For each compile config (default: every robot's straight and turned cell, :data:`CELLS`):
`thinkfast-compile tree CONFIG -o DIR/NAME.h5 --if-changed`, `thinkfast-compile verify`, then
`thinkfast-sim bench --throws N --seed S --feints 0 --planners tree,naive,naive-paper,oracle,
oracle_seen --json` (paired: every planner on the same throws). Writes DIR/NAME.json and prints
one Markdown table (blocked of N, Wilson 95 % for the tree, whether the oracle bounds every
planner, the tree's size and fingerprint), then the machine and the load. Exit 1 when a verify
fails or the oracle does not bound a planner.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
PLANNERS = ("tree", "naive", "naive-paper", "oracle", "oracle_seen")
CELLS = (
    "trees/irb1600_default.toml",
    "trees/irb1600_turned30.toml",
    "trees/irb1600_6_120_default.toml",
    "trees/irb1600_6_120_turned30.toml",
    "trees/irb2600_12_165_default.toml",
    "trees/irb2600_12_165_turned30.toml",
)


def run(argv: list[str]) -> tuple[str, float, int]:
    """Run a command; its stdout, wall time and exit status (stderr echoed on failure)."""
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()[-600:]}")
    return proc.stdout, time.perf_counter() - t0, proc.returncode


def one_cell(config: Path, out: Path, throws: int, seed: int, jobs: int) -> dict:
    name = config.stem
    tree = out / f"{name}.h5"
    _, t_compile, rc = run([str(BIN / "thinkfast-compile"), "tree", str(config), "-o", str(tree),
                            "--if-changed", "--jobs", str(jobs)])  # fmt: skip
    if rc:
        sys.exit(f"{config}: compile failed")
    info, _, _ = run([str(BIN / "thinkfast-compile"), "info", str(tree)])
    text, t_verify, rc_verify = run(
        [str(BIN / "thinkfast-compile"), "verify", str(tree), "--jobs", str(jobs)]
    )
    bench, t_bench, rc = run([
        str(BIN / "thinkfast-sim"), "bench", "--tree", str(tree), "--throws", str(throws),
        "--seed", str(seed), "--feints", "0", "--planners", ",".join(PLANNERS),
        "-j", str(jobs), "--json",
    ])  # fmt: skip
    if rc:
        sys.exit(f"{tree}: bench failed")
    (out / f"{name}.json").write_text(bench)
    summary = json.loads(bench)
    fp = next((ln.split()[1] for ln in info.splitlines() if ln.startswith("fingerprint")), "?")
    size = info.splitlines()[0].removeprefix("action tree: ") if info else ""
    return {
        "name": name,
        "summary": summary,
        "verify": rc_verify == 0 and "verify: OK" in text,
        "fingerprint": fp,
        "size": size,
        "seconds": {
            "compile": round(t_compile, 1),
            "verify": round(t_verify, 1),
            "bench": round(t_bench, 1),
        },  # fmt: skip
    }


def table(rows: list[dict], throws: int) -> str:
    head = ["cell", "robot", "plane", *PLANNERS, "tree 95 % CI", "oracle bounds all", "verify"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        s, cell = r["summary"], r["summary"]["cell"]
        p = cell["plane"]
        plane = f"x {p['distance']:g} m" + (
            f", yaw {p.get('yaw', 0) * 57.29577951308232:.0f} deg, offset {p.get('offset', 0):g} m"
            if p.get("yaw") or p.get("offset")
            else ""
        )
        blocked = {k: s["planners"][k]["blocked"] for k in PLANNERS}
        lo, hi = s["planners"]["tree"]["ci95"]
        bound = all(blocked["oracle"] >= v for v in blocked.values())
        lines.append(
            "| "
            + " | ".join(
                [
                    r["name"],
                    cell["robot"],
                    plane,
                    *(str(blocked[k]) for k in PLANNERS),
                    f"[{lo * 100:.1f}, {hi * 100:.1f}] %",
                    "yes" if bound else "**no**",
                    "OK" if r["verify"] else "**FAILED**",
                ]
            )
            + " |"  # fmt: skip
        )
    lines.append(f"\n({throws} throws per cell, no feints; blocked counts of {throws})")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("configs", nargs="*", type=Path, help="compile configs (default: CELLS)")
    ap.add_argument("--throws", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "cells_out")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    configs = a.configs or [ROOT / c for c in CELLS]
    rows = []
    for c in configs:
        r = one_cell(c, a.out, a.throws, a.seed, a.jobs)
        print(f"{r['name']}: {r['size']}; fingerprint {r['fingerprint']}; seconds {r['seconds']}",
              file=sys.stderr, flush=True)  # fmt: skip
        rows.append(r)
    print(table(rows, a.throws))
    from thinkfast.machine import machine_info

    m = machine_info()
    print(f"\nmachine: {m.get('cpu', '?')}, {os.cpu_count()} cores; load average at the end "
          f"{[round(x, 2) for x in os.getloadavg()]}")  # fmt: skip
    (a.out / "cells.json").write_text(json.dumps(
        [{k: v for k, v in r.items() if k != "summary"} for r in rows], indent=1))  # fmt: skip
    ok = all(r["verify"] for r in rows) and all(
        all(r["summary"]["planners"]["oracle"]["blocked"] >= v["blocked"]
            for v in r["summary"]["planners"].values())
        for r in rows
    )  # fmt: skip
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
