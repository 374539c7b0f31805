"""Detection delivery over zenoh on loopback: plain TCP against the secured cell's mutual TLS.

Two links are up at once in this one process, each a camera node's session connected to a
daemon-like session: plain TCP (both ends ``tcp/127.0.0.1``, no scouting) and the secured cell's
(``thinkfast-cell certs``: ``daemon.json5`` and ``camera-base.json5`` from a fresh CA in a
temporary directory, endpoints moved to free loopback ports, mutual TLS and both nodes' access
control in force as written). The daemon side is the daemon's own zenoh edge
(:class:`~thinkfast.daemon.zenoh_edge.ZenohIO`: its FIFO subscriber on
``thinkfast/detections``, and on the TLS link the sender gate that admits a detection only from
the camera's node); the camera side puts with ``attributed_put`` as the camera nodes do.

One detection message (``encode_detection``: stamp, position, frame, confidence, seq, camera;
about 130 bytes of JSON, what ``thinkfast-detect`` sends) goes over each link in turn, TCP then
TLS, half a period apart, so that each link carries the camera's rate (``--rate``, 50 Hz) and
no two samples are in flight together; ``--samples`` pairs are counted after ``--warmup``.
Latency is the receive time minus the send time on one clock (``time.perf_counter_ns`` in this
process): the send time just before ``put``, the receive time as soon as a thread blocked on
the subscriber's FIFO (``recv``, one thread per link, the same code for both) has the sample;
the payload's copy and the gate's check (TLS link) come after that stamp and are given on their
own (``copy_us``, ``gate_us``). The daemon itself drains its FIFO from its control loop once per
cycle, which adds up to one cycle to both transports alike and is not measured here. The
garbage collector is off while samples are sent (the set-up's objects frozen first).

The result: per transport n, lost, median, p90, p99 and max [us]; the paired difference TLS
minus TCP over the pairs both delivered (median, 95 % percentile-bootstrap interval of the
median, ``--seed``; the sign test's two-sided p); each link's set-up once (the camera's
``open_session`` started to the first detection the daemon side admitted; the camera puts one
every 0.2 ms until then; ``open`` is the session open alone); and a check of the daemon's
access control: a ``viewer-status`` node (its own access control turned off, so its puts leave
it) puts detections on the TLS link, and none may arrive. Both ends share the host's cores with
whatever else runs there: the load average is given at the start and the end.

    python bench/zenoh_delivery.py                    # 2000 pairs at 50 Hz: about 45 s
    python bench/zenoh_delivery.py --samples 200 --json
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import tempfile
import threading
import time
from importlib import metadata
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thinkfast.cell.certs import CellNodes, write_cell  # noqa: E402
from thinkfast.contract import keys  # noqa: E402
from thinkfast.contract.detection import encode_detection  # noqa: E402
from thinkfast.contract.zenoh_session import (  # noqa: E402
    attributed_put,
    close_session,
    free_tcp_port,
    open_session,
    session_config,
)
from thinkfast.daemon.zenoh_edge import ZenohIO  # noqa: E402
from thinkfast.errors import ThinkfastError  # noqa: E402
from thinkfast.machine import machine_info  # noqa: E402
from thinkfast.sim.stats import binomial_half_cdf  # noqa: E402

PREFIX = "thinkfast"  # the key prefix the generated access control names
POSITION = (6.9, 0.1, 1.4)  # m, a ball about 7 m out in the camera's frame
PROBE_SEQ = 10**12  # seq numbers of the set-up probes (the counted samples are below)
ACL_SEQ = 2 * 10**12  # seq numbers of the access-control check's puts
PROBE_EVERY = 0.2e-3  # s between two set-up probes
TRANSPORTS = ("tcp", "tls")
BOOTSTRAP = 2000  # resamples of the paired differences


def detection(seq: int) -> bytes:
    """One detection message as the camera's detector sends it (about 130 bytes)."""
    return encode_detection(time.time(), POSITION, confidence=0.93, seq=seq, camera="base")


class Link:
    """A daemon-like session (the daemon's zenoh edge) and a camera session connected to it.

    The daemon side opens at construction, with a thread blocked on its subscriber's FIFO that
    stamps each sample on arrival; :meth:`connect` opens the camera side and times the set-up.
    """

    def __init__(self, name: str, daemon_conf, camera_conf):
        self.name, self.camera_conf = name, camera_conf
        self.io = ZenohIO(daemon_conf, PREFIX)
        self.arrivals: dict[int, tuple[int, int, int, bool]] = {}
        # seq -> (received, payload copied, gate passed [ns], admitted)
        self.sent: dict[int, int] = {}  # seq -> put ns
        self.camera = None
        self.put = None
        self.setup: dict = {}
        self._thread = threading.Thread(target=self._receive, name=f"rx-{name}", daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        sub, gate, clock = self.io.sub, self.io.gate, time.perf_counter_ns
        while True:
            try:
                sample = sub.recv()
            except Exception:  # the session closed: the channel is empty and closed
                return
            t = clock()
            payload = sample.payload.to_bytes()
            t_gate = clock()
            ok = gate is None or gate.admit(sample, payload)
            self.arrivals[json.loads(payload)["seq"]] = (t, t_gate, clock(), ok)

    def connect(self, timeout: float = 10.0) -> None:
        """Open the camera session and put probes until the daemon side admits one."""
        t0 = time.perf_counter_ns()
        self.camera = open_session(self.camera_conf)
        t_open = time.perf_counter_ns()
        self.put = attributed_put(self.camera.declare_publisher(keys.detections(PREFIX)))
        seq, end = PROBE_SEQ, time.perf_counter() + timeout
        while time.perf_counter() < end:
            self.put(detection(seq))
            seq += 1
            time.sleep(PROBE_EVERY)
            admitted = [a[0] for s, a in list(self.arrivals.items()) if s >= PROBE_SEQ and a[3]]
            if admitted:
                probes = [a for s, a in list(self.arrivals.items()) if s >= PROBE_SEQ]
                self.setup = {
                    "open_ms": round((t_open - t0) / 1e6, 2),
                    "first_sample_ms": round((min(admitted) - t0) / 1e6, 2),
                    "probes_put": seq - PROBE_SEQ,
                    "probes_refused": sum(not a[3] for a in probes),
                }
                return
        raise ThinkfastError(f"{self.name}: no detection admitted {timeout:g} s after open")

    def close(self) -> None:
        if self.camera is not None:
            close_session(self.camera)
        self.io.close()
        self._thread.join(5.0)


def make_links(directory: Path) -> dict[str, Link]:
    """The plain TCP link and the secured cell's TLS link (its files written in
    ``directory``), both on free loopback ports."""
    write_cell(directory, CellNodes(cameras=("base",), viewers=("status",)))
    tcp = f"tcp/127.0.0.1:{free_tcp_port()}"
    tls = f"tls/127.0.0.1:{free_tcp_port()}"
    # the camera node listens for its bridge's frames: on a free port here too
    frames = f"tls/127.0.0.1:{free_tcp_port()}"
    return {
        "tcp": Link(
            "tcp",
            session_config(listen=[tcp], multicast=False),
            session_config(connect=[tcp], multicast=False),
        ),
        "tls": Link(
            "tls",
            session_config(config_file=directory / "daemon.json5", listen=[tls]),
            session_config(
                config_file=directory / "camera-base.json5", connect=[tls], listen=[frames]
            ),
        ),
    }


def check_acl(directory: Path, link: Link, n: int = 20) -> dict:
    """Put ``n`` attributed detections on the TLS link from the cell's viewer node with its own
    access control off: the daemon's must drop them all (only ``camera-*`` may put)."""
    tls_ep = link.io.describe()["listen"][0]
    conf = session_config(config_file=directory / "viewer-status.json5", connect=[tls_ep])
    conf.insert_json5("access_control/enabled", "false")
    viewer = open_session(conf)
    try:
        put = attributed_put(viewer.declare_publisher(keys.detections(PREFIX)))
        time.sleep(0.5)  # the daemon's subscriber declared to the viewer
        for i in range(n):
            put(detection(ACL_SEQ + i))
            time.sleep(0.01)
        time.sleep(0.5)
    finally:
        close_session(viewer)
    got = [s for s in list(link.arrivals) if s >= ACL_SEQ]
    return {"node": "viewer-status", "put": n, "arrived": len(got)}


def send_pairs(links: dict[str, Link], n: int, rate: float) -> float:
    """Put ``n`` detections on each link, in turn, half a period apart; returns the seconds."""
    order = [links[t] for t in TRANSPORTS]
    period = 1.0 / rate
    start = time.perf_counter() + 0.05
    for k in range(n):
        for j, link in enumerate(order):
            due = start + (k + j / len(order)) * period
            pause = due - time.perf_counter()
            if pause > 0:
                time.sleep(pause)
            seq = len(order) * k + j
            payload = detection(seq)
            link.sent[seq] = time.perf_counter_ns()
            link.put(payload)
    time.sleep(0.5)  # the last ones in
    return time.perf_counter() - start


def percentiles(us: np.ndarray) -> dict:
    if not len(us):
        return {"median_us": None, "p90_us": None, "p99_us": None, "max_us": None}
    p50, p90, p99 = np.percentile(us, [50, 90, 99])
    return {
        "median_us": round(float(p50), 1),
        "p90_us": round(float(p90), 1),
        "p99_us": round(float(p99), 1),
        "max_us": round(float(us.max()), 1),
    }


def latencies(link: Link, first_seq: int) -> dict[int, float]:
    """Counted seq -> latency [us] of the samples ``link`` delivered."""
    return {
        s: (link.arrivals[s][0] - t) / 1e3
        for s, t in link.sent.items()
        if s >= first_seq and s in link.arrivals
    }


def paired(tcp: dict[int, float], tls: dict[int, float], seed: int) -> dict:
    """TLS minus TCP over the pairs both delivered (pair k: seq 2k on TCP, 2k + 1 on TLS)."""
    ks = sorted(k for k in (s // 2 for s in tcp) if 2 * k + 1 in tls)
    d = np.array([tls[2 * k + 1] - tcp[2 * k] for k in ks])
    if not len(d):
        return {"pairs": 0}
    rng = np.random.default_rng(seed)
    boot = np.median(d[rng.integers(0, len(d), size=(BOOTSTRAP, len(d)))], axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    pos, neg = int((d > 0).sum()), int((d < 0).sum())
    return {
        "pairs": len(d),
        "median_us": round(float(np.median(d)), 1),
        "ci95_us": [round(float(lo), 1), round(float(hi), 1)],
        "mean_us": round(float(d.mean()), 1),
        "tls_slower": pos,
        "tls_faster": neg,
        "sign_test_p": min(1.0, 2.0 * binomial_half_cdf(min(pos, neg), pos + neg)),
        "bootstrap": BOOTSTRAP,
        "seed": seed,
    }


def run(args) -> dict:
    load_start = [round(x, 2) for x in os.getloadavg()]
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tf-zenoh-delivery-") as tmp:
        directory = Path(tmp)
        links = make_links(directory)
        try:
            for t in TRANSPORTS:  # both daemon sides up; one camera side at a time
                links[t].connect()
            gc.collect()
            gc.freeze()
            gc.disable()
            try:
                wall = send_pairs(links, args.warmup + args.samples, args.rate)
            finally:
                gc.enable()
            acl = check_acl(directory, links["tls"])
            security = {t: links[t].io.as_dict() for t in TRANSPORTS}
        finally:
            for link in links.values():
                link.close()
    first = len(TRANSPORTS) * args.warmup
    lat = {t: latencies(links[t], first) for t in TRANSPORTS}
    out: dict = {
        "payload_bytes": len(detection(len(TRANSPORTS) * (args.warmup + args.samples))),
        "rate_hz": args.rate,
        "samples": args.samples,
        "warmup": args.warmup,
        "transports": {},
    }
    for t in TRANSPORTS:
        link = links[t]
        counted = [s for s in link.sent if s >= first]
        us = np.array(sorted(lat[t].values()))
        handled = [link.arrivals[s] for s in lat[t]]
        out["transports"][t] = {
            "n": len(us),
            "lost": len(counted) - len(us),
            "refused": sum(not link.arrivals[s][3] for s in counted if s in link.arrivals),
            # samples of the other link (none: the two links share no session)
            "foreign": sum(s % 2 != TRANSPORTS.index(t) for s in link.arrivals if s < PROBE_SEQ),
            **percentiles(us),
            # after the stamp, not in the latency: the payload's copy, then the gate (TLS)
            "copy_us": percentiles(np.array([(a[1] - a[0]) / 1e3 for a in handled])),
            "gate_us": percentiles(np.array([(a[2] - a[1]) / 1e3 for a in handled])),
            "setup": link.setup,
            "security": security[t],
        }
    out["paired_tls_minus_tcp"] = paired(lat["tcp"], lat["tls"], args.seed)
    out["acl_check"] = acl
    out["send_s"] = round(wall, 1)
    out["seconds"] = round(time.perf_counter() - started, 1)
    out["load_avg_start"] = load_start
    out["load_avg_end"] = [round(x, 2) for x in os.getloadavg()]
    out["zenoh"] = metadata.version("eclipse-zenoh")
    out["machine"] = machine_info()
    return out


def report(out: dict) -> None:
    m = out["machine"]
    print(f"Detection delivery over zenoh on loopback, camera session -> daemon-like session: "
          f"{out['samples']} pairs ({out['warmup']} more uncounted), each link at "
          f"{out['rate_hz']:g} Hz, TCP and TLS in turn, {out['payload_bytes']}-byte "
          f"detection")  # fmt: skip
    print(f"  {'transport':<9} {'n':>5} {'lost':>4} {'median us':>9} {'p90 us':>8} "
          f"{'p99 us':>8} {'max us':>8}   set-up: open -> first admitted sample")  # fmt: skip
    for t, r in out["transports"].items():
        s = r["setup"]
        print(f"  {t:<9} {r['n']:>5} {r['lost']:>4} {r['median_us']:>9} {r['p90_us']:>8} "
              f"{r['p99_us']:>8} {r['max_us']:>8}   {s['open_ms']} -> {s['first_sample_ms']} ms"
              )  # fmt: skip
    p = out["paired_tls_minus_tcp"]
    if p["pairs"]:
        print(f"  paired TLS - TCP ({p['pairs']} pairs): median {p['median_us']:+} us, 95 % "
              f"[{p['ci95_us'][0]:+}, {p['ci95_us'][1]:+}] (bootstrap, seed {p['seed']}); TLS "
              f"slower in {p['tls_slower']}, faster in {p['tls_faster']}, sign test p "
              f"{p['sign_test_p']:.2g}")  # fmt: skip
    a, tls = out["acl_check"], out["transports"]["tls"]
    print(f"  TLS link: {tls['security']['auth']}, linked {tls['security'].get('linked')}, "
          f"{tls['refused']} refused; samples of the other link: "
          f"{sum(r['foreign'] for r in out['transports'].values())}")  # fmt: skip
    for t, r in out["transports"].items():
        c, g = r["copy_us"], r["gate_us"]
        print(f"  {t} after the stamp (not in the latency): payload copy median "
              f"{c['median_us']} us, sender gate median {g['median_us']} us, p99 {g['p99_us']} "
              f"us")  # fmt: skip
    print(f"  access control: {a['put']} detections put by {a['node']} (its own ACL off), "
          f"{a['arrived']} arrived")  # fmt: skip
    print(f"  machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, zenoh "
          f"{out['zenoh']}; load average {out['load_avg_start']} -> {out['load_avg_end']}; "
          f"{out['seconds']} s")  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=2000, help="counted pairs (2000)")
    ap.add_argument("--rate", type=float, default=50.0, help="Hz on each link (50: the camera's)")
    ap.add_argument("--warmup", type=int, default=50, help="uncounted pairs first (50)")
    ap.add_argument("--seed", type=int, default=1, help="bootstrap resampling (1)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    try:
        if args.samples < 1 or args.warmup < 0 or not 0 < args.rate <= 1000:
            raise ThinkfastError("--samples must be >= 1, --warmup >= 0, --rate in (0, 1000]")
        out = run(args)
    except (ThinkfastError, OSError) as exc:
        print(f"zenoh_delivery: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(out))
    else:
        report(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
