"""How often the live view logs the joints on this machine: a real-time simulated run with the
daemon's ``--rerun save=FILE``, then the joint samples in the file (rate and gaps); with
``--view foxglove`` the daemon's ``--foxglove`` instead, and the samples are the
``/thinkfast/joints/commanded`` messages a WebSocket client (tests/foxglove_client.py) receives.

The view logs a joint sample (at most 50 per second) only when its measured cost fits the time
left before the next EGM packet (docs/LIVE_VIEW.md): the rate is what the host leaves over,
not a setting. Prints a table (and the load average); ``--json`` one object.

    python bench/live_view_rate.py --tree trees/irb1600_default.h5 --throws 3 [--json]
    python bench/live_view_rate.py --view foxglove   # the Foxglove view's
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

ROOT = Path(__file__).resolve().parents[1]


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


def rerun_joint_times(args) -> np.ndarray:
    """A simulated run with ``--rerun save=FILE``; the joint samples' times in the file."""
    with tempfile.TemporaryDirectory() as d:
        rrd = Path(d) / "view.rrd"
        subprocess.run(
            [str(Path(sys.executable).parent / "thinkfast-sim"), "run", "--tree", str(args.tree),
             "--throws", str(args.throws), "--seed", str(args.seed), "--rerun", f"save={rrd}"],
            check=True, capture_output=True,
        )  # fmt: skip
        return joint_times(rrd)


def foxglove_joint_times(args) -> np.ndarray:
    """A simulated run with ``--foxglove``; the log times [s] of the commanded joint states a
    client subscribed to every channel received, sorted."""
    sys.path.insert(0, str(ROOT))
    from tests.foxglove_client import listen
    from thinkfast.contract.zenoh_session import free_tcp_port

    port = free_tcp_port()
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "thinkfast-sim"), "run", "--tree", str(args.tree),
         "--throws", str(args.throws), "--seed", str(args.seed), "--foxglove", f"127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        alive = lambda: proc.poll() is None  # noqa: E731
        _, got = listen(port, lambda got: not alive(), 600.0, 10, alive)
        if proc.wait(60) != 0:
            raise SystemExit("thinkfast-sim run failed")
    finally:
        if proc.poll() is None:
            proc.kill()
    return np.sort(np.array([ns * 1e-9 for ns, _ in got["/thinkfast/joints/commanded"]]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=Path("trees/irb1600_default.h5"))
    ap.add_argument("--throws", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--view", choices=("rerun", "foxglove"), default="rerun")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    t = (foxglove_joint_times if args.view == "foxglove" else rerun_joint_times)(args)
    load1 = os.getloadavg()[0]
    gaps = np.diff(t) if len(t) > 1 else np.array([np.nan])
    span = float(t[-1] - t[0]) if len(t) > 1 else float("nan")
    out = {
        "view": args.view,
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
    print(
        "view      samples  span_s  rate_hz  gap_median_ms  gap_p99_ms  gap_max_ms  load  machine"
    )
    g = out["gap_ms"]
    print(f"{args.view:8s}  {out['samples']:7d}  {out['span_s']:6.1f}  {out['rate_hz'] or 0:7.1f}  "
          f"{g['median']:13.1f}  {g['p99']:10.1f}  {g['max']:10.0f}  {load0:.1f}-{load1:.1f}  "
          f"{out['machine']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
