"""Hostile detection payloads: kinds the contract refuses, published over zenoh in bursts.

Every kind of :data:`KINDS` breaks the detection contract (docs/INTERFACES.md "Detections", and the
README's choices: ``null`` is absent, unknown keys ignored, ``seq`` in [0, 2^63), positions
within 100 m, covariance entries within 1e4 m^2, stamps within 1 s past / 0.5 s future), so a
daemon must count each as rejected or dropped and accept none. A payload is built around a
plausible ball (5 m in front of the camera, stamped now), with one thing wrong.

:func:`fuzz_stream` runs in a process of its own (``python -m bench.faultkit.fuzz``) so that
its bursts of several kHz do not steal the fault controller's time.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from thinkfast.contract import keys

BIG = 1 << 20  # 1 MB


def _base(now: float) -> dict:
    return {"stamp": now, "position": [5.0, 0.1, 1.0], "frame": "camera", "seq": 1}


def _with(**kw):
    return lambda r, now: json.dumps({**_base(now), **kw}).encode()


def _without(key):
    return lambda r, now: json.dumps({k: v for k, v in _base(now).items() if k != key}).encode()


def _raw(text: str):
    return lambda r, now: text.replace("NOW", repr(now)).encode()


def _nested(open_: str, close: str, depth: int = 100_000):
    return lambda r, now: (open_ * depth + close * depth).encode()


_COV = [0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01]
NAN, INF = float("nan"), float("inf")
KINDS = {
    # bytes that are not a JSON object
    "random_bytes": lambda r, now: r.bytes(int(r.integers(1, 300))),
    "empty": lambda r, now: b"",
    "invalid_utf8": lambda r, now: b'{"stamp": \xff\xfe, "position": [5, 0, 1]}',
    "utf16": lambda r, now: json.dumps(_base(now) | {"position": [NAN, 0, 0]}).encode("utf-16"),
    "bom_nan_position": lambda r, now: b"\xef\xbb\xbf" + _with(position=[NAN, 0, 0])(r, now),
    "truncated": lambda r, now: json.dumps(_base(now)).encode()[:-7],
    "trailing_garbage": lambda r, now: json.dumps(_base(now)).encode() + b" }{ x",
    "json_array": _raw("[NOW, 5.0, 0.1, 1.0]"),
    "json_string": _raw('"stamp NOW"'),
    "json_number": _raw("NOW"),
    "json_null": _raw("null"),
    "json_true": _raw("true"),
    "empty_object": _raw("{}"),
    "deep_object": _nested('{"a":', "}"),
    "deep_array": _nested("[", "]"),
    "null_bytes": lambda r, now: b'{"stamp": 1\x00, "position": [5, 0, 1]}',
    # stamp
    "missing_stamp": _without("stamp"),
    "stamp_string": _with(stamp="now"),
    "stamp_null": _with(stamp=None),
    "stamp_nan": _with(stamp=NAN),
    "stamp_inf": _with(stamp=INF),
    "stamp_minus_inf": _with(stamp=-INF),
    "stamp_negative": _with(stamp=-1.0),
    "stamp_bool": _with(stamp=True),
    "stamp_huge_int": _raw('{"stamp": 1' + "0" * 400 + ', "position": [5, 0.1, 1]}'),
    "stamp_huge_exponent": _raw('{"stamp": 1e99999, "position": [5, 0.1, 1]}'),
    "stamp_far_past": lambda r, now: _with(stamp=now - 1000.0)(r, now),
    "stamp_far_future": lambda r, now: _with(stamp=now + 1000.0)(r, now),
    "stamp_list": lambda r, now: _with(stamp=[now])(r, now),
    # position
    "missing_position": _without("position"),
    "position_two": _with(position=[5.0, 0.1]),
    "position_four": _with(position=[5.0, 0.1, 1.0, 0.0]),
    "position_strings": _with(position=["5", "0.1", "1"]),
    "position_nan": _with(position=[5.0, NAN, 1.0]),
    "position_inf": _with(position=[INF, 0.1, 1.0]),
    "position_1e300": _with(position=[1e300, 0.1, 1.0]),
    "position_150m": _with(position=[150.0, 0.1, 1.0]),
    "position_bools": _with(position=[True, False, True]),
    "position_nested": _with(position=[[5.0], [0.1], [1.0]]),
    "position_object": _with(position={"x": 5.0, "y": 0.1, "z": 1.0}),
    "position_null": _with(position=None),
    "position_string": _with(position="5, 0.1, 1"),
    "duplicate_key_nan": lambda r, now: (
        json.dumps(_base(now)).encode()[:-1] + b', "position": [NaN, 0, 0]}'
    ),
    "homoglyph_stamp_key": lambda r, now: json.dumps(
        {"\u0455tamp": now, "position": [5.0, 0.1, 1.0]}
    ).encode(),
    # frame, covariance, confidence, seq
    "frame_world": _with(frame="world"),
    "frame_number": _with(frame=7),
    "frame_empty": _with(frame=""),
    "frame_upper": _with(frame="CAMERA"),
    "cov_short": _with(covariance=[0.01, 0.01, 0.01]),
    "cov_nan": _with(covariance=[NAN] + _COV[1:]),
    "cov_asymmetric": _with(covariance=[0.01, 0.5, 0, 0, 0.01, 0, 0, 0, 0.01]),
    "cov_negative": _with(covariance=[-0.01, 0, 0, 0, -0.01, 0, 0, 0, -0.01]),
    "cov_huge": _with(covariance=[1e5, 0, 0, 0, 1e5, 0, 0, 0, 1e5]),
    "cov_strings": _with(covariance=["a"] * 9),
    "confidence_7": _with(confidence=7.0),
    "confidence_negative": _with(confidence=-0.5),
    "confidence_string": _with(confidence="high"),
    "seq_negative": _with(seq=-1),
    "seq_2_63": _with(seq=1 << 63),
    "seq_float": _with(seq=1.5),
    "seq_string": _with(seq="1"),
    # 1 MB payloads
    "mb_random": lambda r, now: r.bytes(BIG),
    "mb_number_array": lambda r, now: ("[" + ",".join(["1.5"] * (BIG // 4)) + "]").encode(),
    "mb_position_string": _with(position="x" * BIG),
    "mb_padded_nan": lambda r, now: _with(position=[NAN, 0, 0], pad="y" * BIG)(r, now),
}
HEAVY = {k for k in KINDS if k.startswith("mb_") or k.startswith("deep_")}


def payloads(rng: np.random.Generator, n: int, heavy_share: float = 0.003):
    """``n`` (kind, payload-maker) pairs: every kind at least once, heavy ones rarely."""
    light = [k for k in KINDS if k not in HEAVY]
    out = list(KINDS)
    while len(out) < n:
        pool = sorted(HEAVY) if rng.random() < heavy_share else light
        out.append(pool[int(rng.integers(len(pool)))])
    rng.shuffle(out)
    return out[:n] if n >= len(KINDS) else out


def fuzz_stream(connect: str, prefix: str, n: int, seconds: float, seed: int,
                burst_hz: float = 5000.0) -> dict:  # fmt: skip
    """Publish ``n`` fuzzed payloads over ``seconds`` in bursts (at ``burst_hz`` inside a
    burst); returns what was sent (per kind, bursts, the fastest burst's rate)."""
    import zenoh

    from thinkfast.contract.zenoh_session import open_peer

    rng = np.random.default_rng(seed)
    session = open_peer(connect=[connect])
    pub = session.declare_publisher(
        keys.detections(prefix), congestion_control=zenoh.CongestionControl.BLOCK
    )
    kinds = payloads(rng, n)
    counts: dict[str, int] = {}
    t0, i, bursts, best = time.time(), 0, 0, 0.0
    time.sleep(0.5)  # routes up
    while i < len(kinds):
        size = min(int(rng.integers(20, 400)), len(kinds) - i)
        tb = time.perf_counter()
        for j in range(size):
            wait = tb + j / burst_hz - time.perf_counter()
            if wait > 0.001:  # a few payloads per millisecond, sleeping in between (no spinning)
                time.sleep(wait)
            kind = kinds[i]
            pub.put(KINDS[kind](rng, time.time()))
            counts[kind] = counts.get(kind, 0) + 1
            i += 1
        bursts += 1
        best = max(best, size / max(time.perf_counter() - tb, 1e-6))
        left = len(kinds) - i
        if left:
            pause = max(0.0, (t0 + seconds - time.time()) / max(1, left / 200))
            time.sleep(min(pause, 1.0) * rng.uniform(0.5, 1.5))
    pub.undeclare()
    session.close()
    return {"sent": i, "kinds": len(counts), "per_kind": counts, "bursts": bursts,
            "max_burst_hz": round(best), "seconds": round(time.time() - t0, 2)}  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", required=True, help="zenoh endpoint of the daemon")
    ap.add_argument("--prefix", default="thinkfast")
    ap.add_argument("--n", type=int, default=10_000, help="payloads")
    ap.add_argument("--seconds", type=float, default=20.0, help="spread over about this long")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if not math.isfinite(a.seconds) or a.seconds <= 0 or a.n < 1:
        ap.error("--n >= 1 and --seconds > 0")
    print(json.dumps(fuzz_stream(a.connect, a.prefix, a.n, a.seconds, a.seed)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
