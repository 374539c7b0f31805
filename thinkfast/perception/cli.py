"""``thinkfast-detect``: camera frames over zenoh in, ball detections over zenoh out."""

from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

import typer

from thinkfast.cli_util import (
    KEY_PREFIX,
    ZENOH_CONFIG,
    ZENOH_CONNECT,
    ZENOH_LISTEN,
    ZenohConfigFile,
    ZenohEndpoints,
    make_app,
    run_app,
)

app = make_app("thinkfast perception: ball detections from ZED frames (zenoh in, zenoh out).")
app.info.no_args_is_help = False  # every option has a default: run with them


@app.command()
def run(
    config: Path | None = typer.Option(None, "--config", help="detector configuration (TOML)"),
    key_prefix: str = KEY_PREFIX,
    zenoh_connect: ZenohEndpoints = ZENOH_CONNECT,
    zenoh_listen: ZenohEndpoints = ZENOH_LISTEN,
    zenoh_config: ZenohConfigFile = ZENOH_CONFIG,
    frame: str | None = typer.Option(
        None, "--frame", help="frame of the detections: camera or base (default: the config's)"
    ),
    source: str | None = typer.Option(
        None, "--source", help="colour, boxes or auto (default: the config's)"
    ),
    camera: str | None = typer.Option(
        None,
        "--camera",
        help="id of the camera this process serves (docs/CAMERAS.md; default: the config's "
        "camera_id, else the default camera)",
    ),
    threads: int = typer.Option(1, "--threads", help="OpenCV threads (1: one core)"),
    ros_domain: int | None = typer.Option(
        None,
        "--ros-domain",
        help="also publish detections as ROS 2 PointStamped on this domain (docs/ROS2.md)",
    ),
    print_config: bool = typer.Option(
        False, "--print-config", help="print every detector config default as TOML and exit"
    ),
) -> None:
    """Run until SIGINT/SIGTERM, then print the counts (one JSON line) and exit 0."""
    import dataclasses

    import cv2

    from thinkfast.contract.zenoh_session import session_config
    from thinkfast.errors import ConfigError
    from thinkfast.perception.config import SOURCES, load_detect_config
    from thinkfast.perception.node import DetectorNode

    if print_config:
        from thinkfast.perception.config import detect_config_toml

        print(detect_config_toml(), end="")
        return
    cfg = load_detect_config(config)
    if frame is not None:
        if frame not in ("camera", "base"):
            raise ConfigError("--frame", None, f"{frame!r} is not one of camera, base")
        cfg = dataclasses.replace(cfg, frame=frame)
    if source is not None:
        if source not in SOURCES:
            raise ConfigError("--source", None, f"{source!r} is not one of {', '.join(SOURCES)}")
        cfg = dataclasses.replace(cfg, source=source)
    if camera is not None:
        from thinkfast.perception.config import check

        cfg = check(dataclasses.replace(cfg, camera_id=camera), "--camera")
    if threads < 1:
        raise ConfigError("--threads", None, f"must be >= 1, got {threads}")
    cv2.setNumThreads(threads)
    if ros_domain is not None:
        from thinkfast.contract.ros import check_options

        check_options(ros_domain, key_prefix)
    conf = session_config(
        connect=zenoh_connect or (), listen=zenoh_listen or (), config_file=zenoh_config
    )
    node = DetectorNode(cfg, conf, key_prefix, ros_domain=ros_domain)
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _f: stop.append(signum))
    print(
        f"thinkfast-detect: {cfg.source} -> {key_prefix}/detections ({cfg.frame}"
        + (f", camera {cfg.camera_id}" if cfg.camera_id else "")
        + ")",
        file=sys.stderr,
    )
    try:
        while not stop:
            if not node.step():
                time.sleep(0.0005)
        node.publish_status(time.time())
    finally:
        node.close()
    print(json.dumps(node.counters.as_dict()), flush=True)


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-detect", argv))
