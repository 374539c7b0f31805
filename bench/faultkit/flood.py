"""A bounded UDP flood at the daemon's EGM port from another socket, in a process of its own.

Garbage and valid-looking ``EgmRobot`` messages (their own seqno/tm, joints near home) at a high
rate, bounded three ways: loopback only, at most ``max_packets`` datagrams, at most ``seconds``.
Its own process keeps the flood from competing with the fault controller for the GIL. It prints
one JSON line: datagrams sent (valid-looking ones among them) and replies its socket received.

    python -m bench.faultkit.flood --port 6510 --rate 20000 --seconds 3
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import time

import numpy as np

from bench.faultkit import spawn
from bench.faultkit.egm_pb import robot_message
from bench.faultkit.senders import malformed_datagram, recv_stamped

MAX_RATE = 100_000  # datagrams per second
MAX_PACKETS = 500_000
MAX_SECONDS = 30.0


def flood(port: int, rate: float, seconds: float, max_packets: int, valid_share: float, seed: int):
    """Send the flood to ``127.0.0.1:port``; returns the counts (see the module doc)."""
    rate, seconds = min(rate, MAX_RATE), min(seconds, MAX_SECONDS)
    max_packets = min(max_packets, MAX_PACKETS)
    rng = np.random.default_rng(seed)
    home = np.array([0.0, -0.058, 0.372, 0.0, -0.314, 0.0])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    target = ("127.0.0.1", int(port))
    sent = valid = replies = dropped = 0
    t0 = time.perf_counter()
    while sent < max_packets:
        now = time.perf_counter() - t0
        if now >= seconds:
            break
        due = min(int(now * rate) + 1, max_packets)
        while sent < due:
            sent += 1
            msg = robot_message(sent, 4 * sent, home + rng.normal(0.0, 0.05, 6), unix_time=now)
            if rng.random() >= valid_share:
                msg = malformed_datagram(rng, msg)
            else:
                valid += 1
            try:
                sock.sendto(msg, target)
            except OSError:  # ENOBUFS and the like: the flood outran the kernel
                dropped += 1
        replies += sum(1 for _ in recv_stamped(sock))
        time.sleep(0.0005)
    wall = time.perf_counter() - t0
    time.sleep(0.3)
    replies += sum(1 for _ in recv_stamped(sock))
    sock.close()
    return {"sent": sent, "valid_looking": valid, "send_errors": dropped, "replies": replies,
            "seconds": round(wall, 3), "rate": round(sent / max(wall, 1e-9))}  # fmt: skip


class Flood:
    """Run :func:`flood` in a child process; :meth:`result` waits for its counts."""

    def __init__(self, port: int, rate=20_000.0, seconds=3.0, max_packets=60_000, valid_share=0.3,
                 seed=0):  # fmt: skip
        args = ("--port", str(port), "--rate", str(rate), "--seconds", str(seconds),
                "--max-packets", str(max_packets), "--valid-share", str(valid_share),
                "--seed", str(seed))  # fmt: skip
        self.proc = spawn("flood", *args, stdout=subprocess.PIPE, text=True)

    def result(self, timeout: float = MAX_SECONDS + 10) -> dict:
        try:
            out, _ = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            return {"error": "flood process timed out"}
        try:
            return json.loads(out.strip().splitlines()[-1])
        except (ValueError, IndexError):
            return {"error": f"flood process exit {self.proc.returncode}"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--port", type=int, required=True, help="the daemon's EGM port on 127.0.0.1")
    ap.add_argument("--rate", type=float, default=20_000.0, help=f"per second (<= {MAX_RATE})")
    ap.add_argument("--seconds", type=float, default=3.0, help=f"(<= {MAX_SECONDS:g})")
    ap.add_argument("--max-packets", type=int, default=60_000, help=f"(<= {MAX_PACKETS})")
    ap.add_argument("--valid-share", type=float, default=0.3, help="valid-looking EgmRobot share")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(json.dumps(flood(a.port, a.rate, a.seconds, a.max_packets, a.valid_share, a.seed)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
