"""Wall-clock figures that tests do not assert: send jitter, publisher lateness, EGM round trip.

The tests check behaviour and accounting (every request answered or counted, nothing early,
nothing lost); how *fast* and how *regular* the real-time parts are on a given machine is
measured here, over more samples than a test would take, and printed as a table (median, p90,
p99, max) with the machine and its load:

- ``controller_send_gap``: a simulated controller on its 4 ms cycle with ``--spin``/``--lead``
  (as in the hot-controller test) against an EGM sensor in another process
  (``egm_latency.py --serve``): |gap - 4 ms| between consecutive sends, and its replies.
- ``publisher_lateness``: detections published on their real-time schedule between two zenoh
  sessions on loopback: arrival minus due time.
- ``egm_serve_rtt``: the daemon's EGM server in its serve thread, answering a client on
  loopback: round trip per request.

    python bench/wallclock.py [--n 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from thinkfast.machine import machine_info

HERE = Path(__file__).resolve().parent
DT = 0.004


def _figures(x: np.ndarray, unit: float = 1e-3) -> dict:
    """median, p90, p99 and max of ``x`` [s], in ``unit`` (ms by default)."""
    x = np.asarray(x, dtype=float) / unit
    return {
        "n": int(x.size),
        "median": float(np.median(x)),
        "p90": float(np.percentile(x, 90)),
        "p99": float(np.percentile(x, 99)),
        "max": float(x.max()),
    }


def controller_send_gap(n: int) -> dict:
    """A spinning simulated controller against a sensor process: send-gap error [ms]."""
    from thinkfast.sim.controller import SimController
    from thinkfast.sim.controller_runner import ControllerRunner

    proc = subprocess.Popen(
        [sys.executable, str(HERE / "egm_latency.py"), "--serve", "127.0.0.1:0"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = int(proc.stdout.readline().split()[1])
        sends: list[float] = []

        class Timed(SimController):
            def robot_message(self):
                sends.append(time.perf_counter())
                return super().robot_message()

        runner = ControllerRunner(
            Timed(), ("127.0.0.1", port), rate_hz=1 / DT, n=n, spin=0.001, lead=0.001
        )
        runner.run()
        runner.join()
    finally:
        proc.stdin.close()
        proc.wait(5)
    st = runner.stats
    out = _figures(np.abs(np.diff(sends[1:]) - DT))
    out.update(sent=st.sent, replies=st.replies, missed=st.missed, late=st.late)
    return out


def publisher_lateness(throws: int) -> dict:
    """Detections of ``throws`` sampled throws on their schedule over loopback zenoh [ms]."""
    from thinkfast.contract import keys
    from thinkfast.contract.frames import CameraExtrinsic
    from thinkfast.contract.zenoh_session import loopback_endpoint, open_peer
    from thinkfast.sim.camera import CameraModelConfig, observe
    from thinkfast.sim.publisher import publish_detections
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    key = keys.detections("wallclock")
    ep = loopback_endpoint()
    pub, sub = open_peer(listen=[ep]), open_peer(connect=[ep])
    late: list[float] = []
    try:
        heard = threading.Event()
        probe = sub.declare_subscriber("wallclock/probe", lambda s: heard.set())
        deadline = time.monotonic() + 5.0
        while not heard.is_set() and time.monotonic() < deadline:
            pub.put("wallclock/probe", b"?")
            time.sleep(0.02)
        probe.undeclare()
        rng = np.random.default_rng(0)
        for th in sample_throws(ThrowConfig(), throws, seed=21):
            dets = sorted(
                observe(th, CameraModelConfig(), CameraExtrinsic(), rng),
                key=lambda d: d.delivery_time,
            )
            got: list[float] = []
            listener = sub.declare_subscriber(key, lambda s, got=got: got.append(time.time()))
            t0 = time.time() + 0.2 - dets[0].capture_stamp
            publish_detections(pub, key, dets, t0_wall=t0)
            time.sleep(0.1)
            listener.undeclare()
            late += [a - (t0 + d.delivery_time) for a, d in zip(got, dets, strict=False)]
    finally:
        sub.close()
        pub.close()
    return _figures(np.array(late))


def egm_serve_rtt(n: int) -> dict:
    """Round trips [ms] through the EGM server's serve thread on loopback."""
    from thinkfast.contract import egm
    from thinkfast.link.egm_server import EgmServer

    def hold(fb, before=None):
        return fb.q_rad, np.zeros(6)

    rtts = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        c.bind(("127.0.0.1", 0))
        c.settimeout(1.0)
        with EgmServer("127.0.0.1:0", hold) as server:
            stop = threading.Event()
            th = threading.Thread(target=server.serve, args=(stop, 0.01))
            th.start()
            try:
                for i in range(n):
                    t0 = time.perf_counter()
                    c.sendto(egm.encode_robot(i, i, np.zeros(6)), server.address)
                    egm.decode_sensor(c.recv(65535))
                    rtts.append(time.perf_counter() - t0)
            finally:
                stop.set()
                th.join(1.0)
    return _figures(np.array(rtts))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=2000, help="controller cycles and round trips")
    ap.add_argument("--throws", type=int, default=20, help="throws published (default 20)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    out = {
        "machine": machine_info(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "controller_send_gap_ms": controller_send_gap(args.n),
        "publisher_lateness_ms": publisher_lateness(args.throws),
        "egm_serve_rtt_ms": egm_serve_rtt(args.n),
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
    if args.json:
        print(json.dumps(out))
        return 0
    m = out["machine"]
    print(f"machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}")
    print(f"load average before/after: {out['load_average']} / {out['load_average_after']}")
    print(f"{'figure [ms]':<26}{'n':>7}{'median':>9}{'p90':>9}{'p99':>9}{'max':>9}")
    for name in ("controller_send_gap_ms", "publisher_lateness_ms", "egm_serve_rtt_ms"):
        f = out[name]
        print(
            f"{name:<26}{f['n']:>7}{f['median']:>9.3f}{f['p90']:>9.3f}{f['p99']:>9.3f}"
            f"{f['max']:>9.3f}"
        )
    g = out["controller_send_gap_ms"]
    print(f"controller: sent {g['sent']}, replies {g['replies']}, missed {g['missed']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
