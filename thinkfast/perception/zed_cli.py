"""``thinkfast-zed``: a ZED camera's frames (ZED SDK, pyzed) over zenoh as camera frame messages.

A process of its own beside ``thinkfast-detect`` (which may run on another host): it grabs from
the SDK and publishes docs/CAMERA_FRAMES.md's message, the detector consumes it.
"""

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

MAX_GRAB_ERRORS = 100  # consecutive failed grabs (about 1 s): the camera is gone
NO_SDK_EXIT = 2

app = make_app("thinkfast ZED bridge: ZED SDK frames -> <prefix>/camera/frame (zenoh).")
app.info.no_args_is_help = False


@app.command()
def run(
    config: Path | None = typer.Option(
        None, "--config", help="detector configuration (TOML): [camera] mode, fps; [zed]"
    ),
    key_prefix: str = KEY_PREFIX,
    zenoh_connect: ZenohEndpoints = ZENOH_CONNECT,
    zenoh_listen: ZenohEndpoints = ZENOH_LISTEN,
    zenoh_config: ZenohConfigFile = ZENOH_CONFIG,
    camera: str | None = typer.Option(
        None, "--camera", help="camera id: publish on <prefix>/camera/ID/frame (docs/CAMERAS.md)"
    ),
    serial: int | None = typer.Option(
        None, "--serial", help="the ZED's serial number (several on one host; default: the first)"
    ),
    frames: int = typer.Option(0, "--frames", help="stop after this many frames (0: never)"),
) -> None:
    """Grab and publish until SIGINT/SIGTERM (or --frames), then print the counts (one JSON
    line) and exit 0."""
    import dataclasses

    from thinkfast.contract.zenoh_session import session_config
    from thinkfast.errors import ConfigError
    from thinkfast.perception.config import check, load_detect_config
    from thinkfast.perception.zed_bridge import SDK_MISSING, ZedBridge, ZedError

    cfg = load_detect_config(config)
    if camera is not None:
        cfg = check(dataclasses.replace(cfg, camera_id=camera), "--camera")
    if frames < 0:
        raise ConfigError("--frames", None, f"must be >= 0, got {frames}")
    try:
        import pyzed.sl as sl
    except ImportError:
        print(f"thinkfast-zed: error: {SDK_MISSING}", file=sys.stderr)
        raise typer.Exit(NO_SDK_EXIT) from None
    conf = session_config(
        connect=zenoh_connect or (), listen=zenoh_listen or (), config_file=zenoh_config
    )
    bridge = ZedBridge(sl, cfg, conf, key_prefix, serial)
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _f: stop.append(signum))
    where = f"{key_prefix}/camera/{cfg.camera_id + '/' if cfg.camera_id else ''}frame"
    print(
        f"thinkfast-zed: {cfg.camera.mode} at {cfg.camera.fps:g} fps, depth "
        f"{cfg.zed.depth_mode} -> {where}",
        file=sys.stderr,
    )
    if abs(bridge.fps - cfg.camera.fps) > 0.5:
        print(
            f"thinkfast-zed: warning: the camera runs at {bridge.fps:g} fps, not camera.fps = "
            f"{cfg.camera.fps:g}: set camera.fps = {bridge.fps:g} in this and the run config",
            file=sys.stderr,
        )
    failed = 0
    try:
        while not stop and not (frames and bridge.counts["published"] >= frames):
            if bridge.step_once():
                failed = 0
                continue
            failed += 1
            if failed >= MAX_GRAB_ERRORS:
                raise ZedError(
                    f"{failed} grabs in a row failed ({bridge.counts['last_error']}): "
                    "camera unplugged or end of recording"
                )
            time.sleep(0.01)
    finally:
        bridge.close()
        print(json.dumps(bridge.counts), flush=True)


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-zed", argv))


if __name__ == "__main__":
    main()
