"""What a busy planner next to the EGM reply loop costs: the same process (GIL) or another one.

The measuring side is the simulated controller of ``bench/egm_latency.py`` (hot client, 4 ms
cycle). The server is ``egm_latency.py``'s ``--serve`` loop (an ``EgmServer`` whose setpoints go
through the safety supervisor) with, running next to it:

* ``none``: nothing;
* ``thread``: a planner stand-in in another thread of the server's process: pure Python and
  small numpy operations without pause (what a filter, a tree choice or a Ruckig call looks like
  to the interpreter: it holds the GIL and lets go every ``--switch-ms``, CPython's
  ``sys.setswitchinterval``);
* ``process``: the same work in a child process (no shared interpreter; it competes for the CPU
  only).

The loads run alternately, ``--repeat`` times each, so that a change of the host's load hits
all of them alike; each run is ``--n`` counted exchanges. Prints one row per load (medians over
the repeats of p50, p99, max round trip and missed cycles) or, with ``--json``, one JSON object.

    python bench/reply_isolation.py --n 5000 --repeat 2 --json
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import egm_latency as el  # noqa: E402  (a sibling script)

LOADS = ("none", "thread", "process")


def planner_stand_in(stop=None) -> None:
    """Busy planner work until ``stop`` is set (None: forever): Python loops over small arrays."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(8, 3))
    while stop is None or not stop.is_set():
        acc = 0.0
        for row in x:
            acc += float(np.dot(row, row)) ** 0.5
        x = x * 0.999 + 0.001 * acc


def serve_loaded(bind: str, load: str, switch_ms: float) -> None:
    """``egm_latency.py --serve`` with ``load`` running next to it."""
    sys.setswitchinterval(switch_ms / 1e3)
    if load == "thread":
        threading.Thread(target=planner_stand_in, daemon=True).start()
    elif load == "process":
        multiprocessing.Process(target=planner_stand_in, daemon=True).start()
    el.serve(bind, False, False, -1)


def one_run(load: str, n: int, switch_ms: float) -> dict:
    child = subprocess.Popen(
        [sys.executable, os.path.abspath(__file__), "--serve", "127.0.0.1:0", "--load", load,
         "--switch-ms", str(switch_ms)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        target = ("127.0.0.1", int(child.stdout.readline().split()[1]))
        out = el.measure(target, n, 250.0, 250, 0.001, 0.001)
    finally:
        child.stdin.close()
        child.wait(10)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=5000, help="counted exchanges per run (5000)")
    ap.add_argument("--repeat", type=int, default=2, help="runs per load, alternating (2)")
    ap.add_argument("--switch-ms", type=float, default=5.0, help="sys.setswitchinterval [ms] (5)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--serve", help=argparse.SUPPRESS)
    ap.add_argument("--load", choices=LOADS, default="none", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.serve:
        serve_loaded(a.serve, a.load, a.switch_ms)
        return 0
    runs: dict[str, list[dict]] = {load: [] for load in LOADS}
    started = time.time()
    for _ in range(a.repeat):
        for load in LOADS:
            runs[load].append(one_run(load, a.n, a.switch_ms))
    table = {
        load: {
            key: float(np.median([r[key] for r in rs]))
            for key in ("p50_ms", "p99_ms", "max_ms", "missed", "late")
        }
        for load, rs in runs.items()
    }
    machine = {**el.machine_info(), "load_avg": [round(x, 2) for x in os.getloadavg()]}
    result = {"n": a.n, "repeat": a.repeat, "switch_ms": a.switch_ms, "loads": table,
              "runs": runs, "machine": machine,
              "wall_s": round(time.time() - started, 1)}  # fmt: skip
    if a.json:
        print(json.dumps(result))
        return 0
    print(f"EGM replies next to a busy planner: {a.n} exchanges x {a.repeat} per load, "
          f"switch interval {a.switch_ms:g} ms")  # fmt: skip
    print(f"  {'load':<8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'missed':>7} {'late':>6}")
    for load, row in table.items():
        print(f"  {load:<8} {row['p50_ms']:8.3f} {row['p99_ms']:8.3f} {row['max_ms']:8.2f} "
              f"{row['missed']:7.0f} {row['late']:6.0f}")  # fmt: skip
    for key, value in machine.items():
        print(f"  {key:<10} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
