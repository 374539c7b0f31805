"""Fault campaign: the real ``thinkfast-run`` daemon against a hostile or faulty ABB cell.

Each scenario starts the daemon (``thinkfast.sim.realtime.start_daemon``, loopback ports), a
simulated controller with injected faults on its own 250 Hz clock (``bench.faultkit``),
zenoh peers and throws seen by the camera model, then checks every command the controller applied
with an independent protobuf decoder (velocity, acceleration, braking jerk, resync after a
silence, limits, finiteness), the daemon's process (no crash, no traceback, exit 0 on
SIGINT/SIGTERM) and its status (no latched fault where none may latch). Missed replies are
attributed to host stalls by a probe process that measures its own sleep overshoot.

    python bench/faults.py                          # every scenario (about 25 min)
    python bench/faults.py --scenario sigint --scenario flood --json
    python bench/faults.py --throws 10              # shorter throw series (default 50)
    python bench/faults.py --scenario none --soak 10 --record   # soak only

One line per scenario (name, PASS/FAIL/ERROR, seconds, figures, what failed); ``--json`` prints
one JSON object. Exit status 0 when every scenario passed, 1 otherwise, 2 on a usage error.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # bench.faultkit

from bench.faultkit.campaign import ORDER, as_json, line, make_context, run_campaign  # noqa: E402
from bench.faultkit.scenario import REGISTRY, Options  # noqa: E402

DEFAULT_TREE = ROOT / "trees" / "irb1600_default.h5"
DEPLOY = ("--spin-ahead-ms", "1", "--cpu", str(max(os.sched_getaffinity(0))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--scenario", action="append", metavar="NAME",
                    help="run this scenario (repeatable, or comma separated; 'none': only the "
                    "soak); default all; --list names them")  # fmt: skip
    ap.add_argument("--list", action="store_true", help="list the scenarios and exit")
    ap.add_argument(
        "--soak",
        type=float,
        default=0.0,
        metavar="MINUTES",
        help="then a soak run: throws every 3 s with the fuzz stream running",
    )
    ap.add_argument("--record", action="store_true", help="the daemon records (--record) always")
    ap.add_argument("--tree", default=str(DEFAULT_TREE), help="tree file (default: the default)")
    ap.add_argument("--throws", type=int, default=50, help="throws per throw series (50)")
    ap.add_argument("--seed", type=int, default=1, help="throws, camera noise and faults (1)")
    ap.add_argument("--quick", action="store_true", help="shortest version of each scenario")
    ap.add_argument("--resync-ms", type=float, default=20.0,
                    help="a controller silence longer than this wants the first command at the "
                    "measured state (20)")  # fmt: skip
    ap.add_argument(
        "--no-rt",
        action="store_true",
        help="no SCHED_FIFO for the simulated controller's loop (used when allowed)",
    )
    ap.add_argument(
        "--deploy",
        action="store_true",
        help=f"the daemon with its deployment options ({' '.join(DEPLOY)})",
    )
    ap.add_argument(
        "--daemon-args",
        default="",
        metavar="ARGS",
        help='more thinkfast-run options, one string (e.g. "--reply-process")',
    )
    a = ap.parse_args(argv)
    if a.list:
        for name in ORDER:
            print(f"{name:<22} {REGISTRY[name][1]}")
        return 0
    names = [n for arg in (a.scenario or [",".join(ORDER)]) for n in arg.split(",") if n]
    unknown = [n for n in names if n not in REGISTRY and n != "none"]
    if unknown or a.throws < 1 or a.soak < 0:
        print(f"faults: unknown scenario {unknown} (see --list)" if unknown else
              "faults: --throws >= 1, --soak >= 0", file=sys.stderr)  # fmt: skip
        return 2
    if not Path(a.tree).is_file():
        print(f"faults: {a.tree}: no tree file; build it with `make demo`", file=sys.stderr)
        return 2
    started = time.time()
    out = sys.stderr if a.json else sys.stdout
    extra = (*(DEPLOY if a.deploy else ()), *shlex.split(a.daemon_args))
    ctx = make_context(Path(a.tree), a.seed, extra,
                       log=lambda m: print(m, file=out, flush=True))  # fmt: skip
    record_dir = Path(tempfile.mkdtemp(prefix="faults-records-")) if a.record else None
    ctx.record_dir = record_dir
    ctx.resync_s, ctx.controller_fifo = a.resync_ms / 1e3, None if a.no_rt else 30
    opts = Options(throws=a.throws, soak_minutes=a.soak, record=a.record, quick=a.quick)
    try:
        report = lambda r: print(line(r), file=out, flush=True)  # noqa: E731
        results = run_campaign(ctx, names, opts, on_result=report)
    finally:
        if record_dir is not None:
            shutil.rmtree(record_dir, ignore_errors=True)
    if a.json:
        print(as_json(results, started))
    else:
        n_pass = sum(r.passed is True for r in results)
        print(f"{n_pass}/{len(results)} passed in {time.time() - started:.0f} s")
    return 0 if all(r.passed for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
