"""A continuous stream of realistic throws over zenoh: sampled throws seen by the ZED model.

One throw every ``--period`` seconds (default 3.5 s: the daemon tracks, blocks, returns home and
waits), drawn by :func:`thinkfast.sim.throws.sample_throws`, observed by the camera model
(noise, outliers, dropouts, latency) and published in real time by
:func:`thinkfast.sim.publisher.publish_detections`. It listens to the daemon's status meanwhile.

``egm_latency.py --daemon`` runs it as a child process with ``--wait-go``: it prints ``READY``
once the daemon's status arrives, starts at a ``go`` line on stdin, stops when stdin closes,
and prints one JSON line (what it published, the daemon's last status). Alone:

    python bench/throw_stream.py --connect tcp/127.0.0.1:7447 --throws 5
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import numpy as np

from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import open_peer
from thinkfast.control.config import load_run_config
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.publisher import publish_detections
from thinkfast.sim.throws import ThrowConfig, sample_throws

LEAD = 1.0  # s from a throw's scheduled release back to the first possible detection (hold)


class StatusLog:
    """The daemon's status messages, kept by a zenoh callback (nothing but appending there)."""

    def __init__(self):
        self.last: dict | None = None
        self.count = 0
        self.work_p99_us: list[float] = []  # per message: p99 of the recent reply work [us]

    def __call__(self, sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        self.last, self.count = msg, self.count + 1
        timing = (msg.get("egm_timing") or {}).get("work_us")
        if timing:
            self.work_p99_us.append(timing["p99"])


def stream(args, stop: threading.Event, go: threading.Event | None) -> dict:
    """Publish throws until ``stop`` (or ``--throws`` of them); returns what was published."""
    extrinsic = load_run_config(args.config).camera
    camera = CameraModelConfig()
    throws = sample_throws(ThrowConfig(), args.throws, args.seed)
    session = _open(args.connect, args.timeout)
    status = StatusLog()
    session.declare_subscriber(keys.status(args.prefix), status)
    deadline = time.time() + args.timeout
    while status.last is None and time.time() < deadline:
        time.sleep(0.05)
    if status.last is None:
        raise RuntimeError(f"no status on {args.prefix}/status within {args.timeout:g} s")
    print("READY", flush=True)
    if go is not None:
        go.wait()
    key = keys.detections(args.prefix)
    sent, throws_done, late, seq = 0, 0, [], 0
    start = time.time() + LEAD
    for i, throw in enumerate(throws):
        t_release = start + i * args.period
        if stop.wait(max(0.0, t_release - LEAD - time.time())):
            break
        rng = np.random.default_rng([args.seed, i])
        dets = observe(throw, camera, extrinsic, rng, t_release_wall=0.0, seq0=seq + 1)
        report = publish_detections(session, key, dets, t0_wall=t_release, stop=stop)
        sent += report.sent
        late.append(report.max_late)
        seq = dets[-1].seq if dets else seq
        throws_done += report.sent == len(dets)
    time.sleep(0.2)  # one more status after the last detection
    session.close()
    return {
        "throws_published": throws_done,
        "detections_published": sent,
        "publish_max_late_ms": round(1e3 * max(late, default=0.0), 2),
        "status_messages": status.count,
        "daemon_work_p99_us_max": max(status.work_p99_us, default=None),
        "status": status.last,
    }


def _open(endpoint: str, timeout: float):
    deadline = time.time() + timeout
    while True:
        try:
            return open_peer(connect=[endpoint])
        except Exception:  # the daemon is still starting: zenoh refuses to connect
            if time.time() > deadline:
                raise
            time.sleep(0.2)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", required=True, help="zenoh endpoint of the daemon")
    ap.add_argument("--prefix", default="thinkfast", help="zenoh key prefix (thinkfast)")
    ap.add_argument("--period", type=float, default=3.5, help="s between throws (3.5)")
    ap.add_argument("--throws", type=int, default=10, help="how many throws at most (10)")
    ap.add_argument("--seed", type=int, default=0, help="throw and camera noise seed (0)")
    ap.add_argument("--config", help="runtime TOML of the daemon (camera extrinsic)")
    ap.add_argument("--timeout", type=float, default=60.0, help="s to wait for the daemon (60)")
    ap.add_argument("--wait-go", action="store_true", help="start at 'go' on stdin, stop at EOF")
    args = ap.parse_args(argv)
    stop = threading.Event()
    go = None
    if args.wait_go:
        go = threading.Event()

        def control() -> None:
            for line in sys.stdin:
                if line.strip() == "go":
                    go.set()
            go.set()
            stop.set()

        threading.Thread(target=control, daemon=True).start()
    try:
        out = stream(args, stop, go)
    except Exception as exc:
        print(f"throw_stream: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
