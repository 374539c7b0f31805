"""How often the live view logs the joints on this machine: a real-time simulated run with the
daemon's ``--rerun save=FILE``, then the joint samples in the file (rate and gaps).

The view logs a joint sample (at most 50 per second) only when its measured cost fits the time
left before the next EGM packet (docs/LIVE_VIEW.md): the rate is what the host leaves over,
not a setting. Prints a table (and the load average); ``--json`` one object.

    python bench/live_view_rate.py --tree trees/irb1600_default.h5 --throws 3 [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def joint_times(rrd: Path) -> np.ndarray:
    """Times [s] of the ``joints/q_cmd`` samples of a saved recording, sorted."""
    import rerun as rr

    ts: list[float] = []
    for c in rr.chunk.RrdReader(rrd).stream():
        if c.entity_path.lstrip("/") == "joints/q_cmd":
            batch = c.to_record_batch()
            if "time" in batch.schema.names:
                ts += (batch.column("time").cast("int64").to_numpy() * 1e-9).tolist()
    return np.sort(np.array(ts))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=Path("trees/irb1600_default.h5"))
    ap.add_argument("--throws", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        rrd = Path(d) / "view.rrd"
        load0 = os.getloadavg()[0]
        subprocess.run(
            [str(Path(sys.executable).parent / "thinkfast-sim"), "run", "--tree", str(args.tree),
             "--throws", str(args.throws), "--seed", str(args.seed), "--rerun", f"save={rrd}"],
            check=True, capture_output=True,
        )  # fmt: skip
        load1 = os.getloadavg()[0]
        t = joint_times(rrd)
    gaps = np.diff(t) if len(t) > 1 else np.array([np.nan])
    span = float(t[-1] - t[0]) if len(t) > 1 else float("nan")
    out = {
        "samples": int(len(t)),
        "span_s": round(span, 2),
        "rate_hz": round(len(t) / span, 2) if span > 0 else None,
        "gap_ms": {
            k: round(1e3 * float(f(gaps)), 1)
            for k, f in (
                ("median", np.median),
                ("p99", lambda g: np.percentile(g, 99)),
                ("max", np.max),
            )
        },  # fmt: skip
        "load": [round(load0, 2), round(load1, 2)],
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
    }
    if args.json:
        print(json.dumps(out))
        return 0
    print("samples  span_s  rate_hz  gap_median_ms  gap_p99_ms  gap_max_ms  load  machine")
    g = out["gap_ms"]
    print(f"{out['samples']:7d}  {out['span_s']:6.1f}  {out['rate_hz'] or 0:7.1f}  "
          f"{g['median']:13.1f}  {g['p99']:10.1f}  {g['max']:10.0f}  {load0:.1f}-{load1:.1f}  "
          f"{out['machine']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
