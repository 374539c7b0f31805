"""The ZED SDK and zenoh edge of ``thinkfast-zed``: grab, convert, publish.

The SDK module (``pyzed.sl``) is passed in, never imported here, so the edge runs on any module
that follows the SDK's API. The camera opens in the mode of ``[camera]`` (``mode`` ->
``sl.RESOLUTION``, ``fps`` -> ``camera_fps``) with ``[zed] depth_mode``, in the SDK's image
coordinates and millimetres (:mod:`thinkfast.perception.zed` converts); each grabbed frame goes
out on ``<prefix>/camera/frame`` (``<prefix>/camera/<id>/frame`` with a ``camera_id``).
"""

from __future__ import annotations

from typing import Any

import zenoh

from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import close_session, open_session
from thinkfast.errors import ThinkfastError
from thinkfast.perception.config import DetectConfig
from thinkfast.perception.zed import SDK_UNITS, frame_payload, xyz_step, zed_frame

SDK_URL = "https://www.stereolabs.com/developers/release"
SDK_MISSING = (
    "the ZED SDK's Python API (pyzed) is not installed: install the ZED SDK from "
    f"{SDK_URL} and run its get_python_api.py with this Python"
)
UNIT = "MILLIMETER"  # the SDK's default, asked for explicitly: the conversion relies on it


class ZedError(ThinkfastError):
    """The camera could not be opened or configured (names the SDK's error code)."""


def init_parameters(sl: Any, cfg: DetectConfig, serial: int | None = None) -> Any:
    """``sl.InitParameters`` for ``cfg``'s camera mode, frame rate and depth mode, for the
    camera with serial number ``serial`` (None: the first the SDK finds).

    Raises:
        ZedError: a mode or depth mode this SDK does not know (names the config key).
    """
    init = sl.InitParameters()
    for key, enum, name in (
        ("camera.mode", sl.RESOLUTION, cfg.camera.mode),
        ("zed.depth_mode", sl.DEPTH_MODE, cfg.zed.depth_mode),
    ):
        if not hasattr(enum, name):
            raise ZedError(f"{key} = {name!r}: this ZED SDK has no {enum.__name__}.{name}")
    init.camera_resolution = getattr(sl.RESOLUTION, cfg.camera.mode)
    init.camera_fps = int(round(cfg.camera.fps))
    init.depth_mode = getattr(sl.DEPTH_MODE, cfg.zed.depth_mode)
    init.coordinate_units = getattr(sl.UNIT, UNIT)
    init.coordinate_system = sl.COORDINATE_SYSTEM.IMAGE
    if serial is not None:
        init.set_from_serial_number(serial)
    return init


class ZedBridge:
    """An open ZED camera and a frame publisher.

    Args:
        sl: the SDK module (``pyzed.sl``) or one that follows its API.
        cfg: detector configuration (``[camera]`` mode and fps, ``camera_id``, ``[zed]``).
        conf: zenoh configuration.
        prefix: key prefix.
        serial: the camera's serial number (several on one host), or None: the first.

    Raises:
        ZedError: the camera did not open (the SDK's error code).
    """

    def __init__(
        self, sl: Any, cfg: DetectConfig, conf: zenoh.Config, prefix: str, serial: int | None = None
    ):
        self.sl, self.cfg = sl, cfg
        self.cam = sl.Camera()
        err = self.cam.open(init_parameters(sl, cfg, serial))
        if err != sl.ERROR_CODE.SUCCESS:
            raise ZedError(f"cannot open the ZED camera: {err} (is it plugged in? ZED_Explorer)")
        info = self.cam.get_camera_information().camera_configuration
        left = info.calibration_parameters.left_cam
        self.intrinsics = (left.fx, left.fy, left.cx, left.cy)
        self.fps = float(info.fps)  # the SDK runs the nearest rate it supports
        self.step = xyz_step(cfg.camera.mode, cfg.zed.xyz_step)
        self.runtime = sl.RuntimeParameters()
        self.left, self.xyz = sl.Mat(), sl.Mat()
        self.counts = {"grabbed": 0, "published": 0, "grab_errors": 0, "last_error": ""}
        self.seq = 0
        try:
            self.session = open_session(conf)
        except BaseException:
            self.cam.close()
            raise
        self.pub = self.session.declare_publisher(keys.camera_frame(prefix, cfg.camera_id or None))

    def step_once(self) -> bool:
        """Grab one frame (blocks until the camera has one) and publish it; whether it did."""
        sl = self.sl
        err = self.cam.grab(self.runtime)
        if err != sl.ERROR_CODE.SUCCESS:
            self.counts["grab_errors"] += 1
            self.counts["last_error"] = str(err)
            return False
        self.counts["grabbed"] += 1
        self.cam.retrieve_image(self.left, sl.VIEW.LEFT)
        self.cam.retrieve_measure(self.xyz, sl.MEASURE.XYZ)
        stamp_ns = self.cam.get_timestamp(sl.TIME_REFERENCE.IMAGE).get_nanoseconds()
        self.seq += 1
        frame = zed_frame(
            self.left.get_data(), self.xyz.get_data(), stamp_ns, self.intrinsics, self.seq,
            SDK_UNITS[UNIT], self.step, self.cfg.zed.stamp_lag,
        )  # fmt: skip
        self.pub.put(frame_payload(frame, self.cfg.zed.xyz_dtype))
        self.counts["published"] += 1
        return True

    def close(self) -> None:
        """Close the camera and the session."""
        self.cam.close()
        close_session(self.session)
