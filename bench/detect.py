"""Perception front end on rendered ZED frames: speed per frame on one core, and the acceptance
figures of issue 7 (detection rate 1-9 m, 3-D error against the noise model, false detections).

    .venv/bin/python bench/detect.py                 # table (1000 + 1000 frames at HD720)
    .venv/bin/python bench/detect.py --json          # one JSON object
    .venv/bin/python bench/detect.py --xyz float16 --xyz-step 2   # what thinkfast-sim sends
    .venv/bin/python bench/detect.py --resolution vga --config VGA.toml  # VGA_DETECT settings
    .venv/bin/python bench/detect.py --zenoh 600     # also: 600 frames at 60 Hz through the
                                                     # real thinkfast-detect process over zenoh

Frames are rendered by thinkfast.sim.images (4 scenes, taken in turn) and encoded as frame
payloads (docs/CAMERA_FRAMES.md); only decoding and detection are timed (what thinkfast-detect
does per frame besides zenoh), pinned to one core with OpenCV on one thread.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thinkfast.machine import machine_info  # noqa: E402
from thinkfast.perception.config import load_detect_config  # noqa: E402
from thinkfast.sim.camera import CameraModelConfig  # noqa: E402
from thinkfast.sim.detect_check import run_check, summary  # noqa: E402
from thinkfast.sim.frame_stream import RESOLUTIONS  # noqa: E402
from thinkfast.sim.images import FrameRenderConfig, FrameRenderer  # noqa: E402


def pin_one_core() -> int | None:
    """Run on one core (the last one allowed) with OpenCV single-threaded; returns the core."""
    cv2.setNumThreads(1)
    try:
        core = max(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        return core
    except (AttributeError, OSError):
        return None


def through_process(scenes, n: int, rate: float, seed: int) -> dict:
    """Publish ``n`` rendered frames at ``rate`` to a real ``thinkfast-detect`` over zenoh on
    loopback; latency from ``put`` to the detection's arrival, and what the detector counted."""
    import threading

    import zenoh

    from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
    from thinkfast.sim.detect_check import sample_balls
    from thinkfast.sim.frame_stream import start_detector, stop_detector, wait_detector

    rng = np.random.default_rng(seed)
    p, vel = sample_balls(n, (1.0, 9.0), scenes[0].camera, rng)
    payloads = [
        scenes[i % len(scenes)].render(0.0, i + 1, p[i], vel[i], 0.2, rng)[0] for i in range(n)
    ]
    port = free_tcp_port()
    proc = start_detector("bench", port, f"tcp/127.0.0.1:{free_tcp_port()}")
    time.sleep(1.0)
    session = open_peer(connect=[f"tcp/127.0.0.1:{port}"])
    arrived: dict[int, float] = {}
    lock = threading.Lock()

    def on_detection(sample) -> None:
        seq = json.loads(sample.payload.to_bytes())["seq"]
        with lock:
            arrived[seq] = time.perf_counter()

    session.declare_subscriber("bench/detections", on_detection)
    wait_detector(session, "bench", proc)
    pub = session.declare_publisher(
        "bench/camera/frame", congestion_control=zenoh.CongestionControl.BLOCK
    )
    time.sleep(0.5)
    sent = {}
    start = time.perf_counter()
    for i, payload in enumerate(payloads):
        time.sleep(max(0.0, start + i / rate - time.perf_counter()))
        sent[i + 1] = time.perf_counter()
        pub.put(payload)
    time.sleep(1.0)
    counts = json.loads(stop_detector(proc) or "{}")
    session.close()
    lat = np.array([arrived[k] - sent[k] for k in arrived]) * 1e3
    return {
        "frames_sent": n,
        "rate_hz": rate,
        "frame_mb": round(len(payloads[0]) / 1e6, 2),
        "detections_received": len(arrived),
        "skipped": counts.get("frames", {}).get("skipped"),
        "latency_p50_ms": round(float(np.median(lat)), 2) if len(lat) else None,
        "latency_p99_ms": round(float(np.percentile(lat, 99)), 2) if len(lat) else None,
        "detector_frame_ms": counts.get("frame_ms"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--frames", type=int, default=1000, help="frames with a ball (and without)")
    ap.add_argument("--resolution", default="hd720", choices=sorted(RESOLUTIONS))
    ap.add_argument("--xyz", default="float32", choices=("float32", "float16"))
    ap.add_argument("--xyz-step", type=int, default=1, help="XYZ image at 1/n resolution")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--config", help="detector configuration (TOML, as thinkfast-detect's)")
    ap.add_argument("--no-pin", action="store_true", help="do not pin to one core")
    ap.add_argument("--zenoh", type=int, default=0, help="frames through thinkfast-detect (0: no)")
    args = ap.parse_args(argv)

    machine = machine_info()  # before pinning: the cores the machine has
    core = None if args.no_pin else pin_one_core()
    size, focal = RESOLUTIONS[args.resolution]
    cam = dataclasses.replace(CameraModelConfig(), image_size=size, focal_px=focal)
    render = FrameRenderConfig(xyz_dtype=args.xyz, xyz_step=args.xyz_step)
    scenes = [FrameRenderer(render, cam, seed) for seed in range(4)]
    start = time.perf_counter()
    cfg = load_detect_config(args.config)
    res = run_check(scenes, cfg, args.frames, args.frames, seed=args.seed)
    elapsed = time.perf_counter() - start
    ms = res.seconds * 1e3
    out = {
        "resolution": f"{args.resolution} {size[0]}x{size[1]}",
        "xyz": f"{args.xyz}, 1/{args.xyz_step}",
        "frames": int(len(ms)),
        "frames_per_s": round(float(1e3 / ms.mean()), 1),
        "p50_ms": round(float(np.median(ms)), 3),
        "p99_ms": round(float(np.percentile(ms, 99)), 3),
        "max_ms": round(float(ms.max()), 3),
        "pinned_core": core,
        "load_average": [round(x, 2) for x in os.getloadavg()],  # other work on the machine
        **summary(res),
        "seconds": round(elapsed, 1),
        "machine": machine,
    }
    if args.zenoh:
        if core is not None:  # the detector process and this publisher share the machine
            os.sched_setaffinity(0, range(os.cpu_count() or 1))
        out["zenoh"] = through_process(scenes, args.zenoh, 60.0, args.seed)
    if args.json:
        print(json.dumps(out))
        return 0
    m = out["machine"]
    print(f"detector on rendered frames: {out['resolution']}, XYZ {out['xyz']}")
    print(f"  {m['cpu']}, {m['cores']} cores (pinned to {core}), Python {m['python']}, "
          f"OpenCV {cv2.__version__}, 1 thread, load average {out['load_average']}")  # fmt: skip
    print(f"  {'frames':>8} {'frames/s':>9} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    print(f"  {out['frames']:>8} {out['frames_per_s']:>9.1f} {out['p50_ms']:>8.3f} "
          f"{out['p99_ms']:>8.3f} {out['max_ms']:>8.3f}")  # fmt: skip
    print(f"  ball 1-9 m: {out['ball_frames']} frames, detected {100 * out['detection_rate']:.2f} %"
          f" (misses {out['misses'] or 'none'})")  # fmt: skip
    print(f"  3-D error: {100 * out['within_3sigma']:.2f} % inside the 3-sigma ellipsoid of the "
          f"noise model; Mahalanobis p50 {out['mahalanobis_p50']}, p99 "
          f"{out['mahalanobis_p99']}, max {out['mahalanobis_max']}; |error| / sigma p99 per "
          f"axis {out['axis_error_p99_sigma']}")  # fmt: skip
    print(f"  no ball: {out['empty_frames']} frames, {out['false_detections']} detections")
    print(f"  ({out['seconds']} s with rendering)")
    if "zenoh" in out:
        z = out["zenoh"]
        print(f"  through thinkfast-detect over zenoh: {z['frames_sent']} frames of "
              f"{z['frame_mb']} MB at {z['rate_hz']:g} Hz, {z['detections_received']} detections, "
              f"{z['skipped']} skipped; put -> detection p50 {z['latency_p50_ms']} ms, p99 "
              f"{z['latency_p99_ms']} ms; in the detector {z['detector_frame_ms']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
