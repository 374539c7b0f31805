"""A stand-in for the ZED SDK's Python module (``pyzed.sl``, SDK 4.x) with a synthetic camera.

It follows the SDK's API as far as ``thinkfast-zed`` uses it (the names, call signatures, return
codes, the ``camera_configuration`` information, BGRA images and 4-channel XYZ from ``get_data``,
``Timestamp.get_nanoseconds``) and renders a scene whose every value the tests can compute: a
plane facing the camera at ``depth_mm(seq)`` in ``COORDINATE_SYSTEM.IMAGE`` (x right, y down, z
forward) and millimetres, NaN on every 7th pixel and +inf on every 11th (no depth / beyond the
range), an image whose B, G, R are column, row and frame counter modulo 256. Tests install it
with ``sys.modules["pyzed.sl"]``.
"""

from __future__ import annotations

import enum
import time
import types
from typing import NamedTuple

import numpy as np


class _Enum(enum.Enum):
    def __str__(self) -> str:  # the SDK prints its codes by name
        return self.name


ERROR_CODE = _Enum("ERROR_CODE", "SUCCESS FAILURE CAMERA_NOT_DETECTED END_OF_SVOFILE_REACHED")
RESOLUTION = _Enum("RESOLUTION", "HD2K HD1080 HD1200 HD720 SVGA VGA AUTO")
DEPTH_MODE = _Enum("DEPTH_MODE", "NONE PERFORMANCE QUALITY ULTRA NEURAL NEURAL_PLUS")
UNIT = _Enum("UNIT", "MILLIMETER CENTIMETER METER INCH FOOT")
COORDINATE_SYSTEM = _Enum(
    "COORDINATE_SYSTEM",
    "IMAGE LEFT_HANDED_Y_UP RIGHT_HANDED_Y_UP RIGHT_HANDED_Z_UP LEFT_HANDED_Z_UP "
    "RIGHT_HANDED_Z_UP_X_FWD",
)
VIEW = _Enum("VIEW", "LEFT RIGHT LEFT_GRAY RIGHT_GRAY DEPTH")
MEASURE = _Enum("MEASURE", "DISPARITY DEPTH CONFIDENCE XYZ XYZRGBA")
TIME_REFERENCE = _Enum("TIME_REFERENCE", "IMAGE CURRENT")
MEM = _Enum("MEM", "CPU GPU")

SIZES = {RESOLUTION.HD720: (1280, 720), RESOLUTION.VGA: (672, 376)}
FOCAL = {RESOLUTION.HD720: 532.0, RESOLUTION.VGA: 265.0}
RATES = {RESOLUTION.HD720: (15, 30, 60), RESOLUTION.VGA: (15, 30, 60, 100)}  # ZED 2i
T0_NS = 1_795_000_000_123_456_789  # the first frame's image timestamp [ns since the epoch]
opened: list[InitParameters] = []  # every InitParameters a Camera was opened with
cameras: list[Camera] = []


def depth_mm(seq: int) -> float:
    """Depth of the synthetic plane in frame ``seq`` (1, 2, ...) [mm]."""
    return 2000.0 + 50.0 * seq


def stamp_ns(seq: int, fps: int) -> int:
    """Image timestamp of frame ``seq`` [ns]."""
    return T0_NS + (seq - 1) * (1_000_000_000 // fps)


class InitParameters:
    """The SDK's defaults (SDK 4.x) for what the bridge sets."""

    def __init__(self, **kw):
        self.camera_resolution = RESOLUTION.AUTO
        self.camera_fps = 0
        self.depth_mode = DEPTH_MODE.NEURAL
        self.coordinate_units = UNIT.MILLIMETER
        self.coordinate_system = COORDINATE_SYSTEM.IMAGE
        self.serial_number = 0  # 0: the first camera found
        for k, v in kw.items():
            if not hasattr(self, k):
                raise AttributeError(k)
            setattr(self, k, v)

    def set_from_serial_number(self, serial_number: int) -> None:
        self.serial_number = serial_number


class RuntimeParameters:
    def __init__(self, **kw):
        self.enable_depth = True


class Resolution(NamedTuple):
    width: int = 0
    height: int = 0


class Timestamp:
    def __init__(self, ns: int):
        self._ns = ns

    def get_nanoseconds(self) -> int:
        return self._ns

    def get_seconds(self) -> int:
        return self._ns // 1_000_000_000


class Mat:
    def __init__(self):
        self._data = np.zeros((0, 0, 4), np.uint8)

    def get_data(self) -> np.ndarray:
        return self._data


class Camera:
    """A synthetic camera that opens in any of :data:`SIZES` and grabs at ``camera_fps``."""

    def __init__(self):
        self.init: InitParameters | None = None
        self.seq = 0
        self.closed = False
        cameras.append(self)

    def open(self, init: InitParameters) -> ERROR_CODE:
        if init.camera_resolution not in SIZES:
            return ERROR_CODE.FAILURE
        opened.append(init)
        self.init = init
        # the SDK runs the closest rate the mode supports (0: the highest)
        rates = RATES[init.camera_resolution]
        self.fps = (
            min(rates, key=lambda r: abs(r - init.camera_fps)) if init.camera_fps else rates[-1]
        )
        w, h = SIZES[init.camera_resolution]
        f = FOCAL[init.camera_resolution]
        left = types.SimpleNamespace(fx=f, fy=f, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0)
        self._info = types.SimpleNamespace(
            camera_configuration=types.SimpleNamespace(
                resolution=Resolution(w, h),
                fps=self.fps,
                calibration_parameters=types.SimpleNamespace(left_cam=left),
            )
        )
        return ERROR_CODE.SUCCESS

    def get_camera_information(self):
        return self._info

    def grab(self, runtime: RuntimeParameters | None = None) -> ERROR_CODE:
        if self.init is None or self.closed:
            return ERROR_CODE.CAMERA_NOT_DETECTED
        time.sleep(1.0 / self.fps)  # a real grab waits for the next frame
        self.seq += 1
        return ERROR_CODE.SUCCESS

    def retrieve_image(self, mat: Mat, view=VIEW.LEFT, type=MEM.CPU, resolution=None):
        assert view == VIEW.LEFT
        mat._data = image(self.init.camera_resolution, self.seq)
        return ERROR_CODE.SUCCESS

    def retrieve_measure(self, mat: Mat, measure=MEASURE.DEPTH, type=MEM.CPU, resolution=None):
        assert measure == MEASURE.XYZ
        assert self.init.coordinate_system == COORDINATE_SYSTEM.IMAGE
        assert self.init.coordinate_units == UNIT.MILLIMETER
        mat._data = xyz_mm(self.init.camera_resolution, self.seq)
        return ERROR_CODE.SUCCESS

    def get_timestamp(self, reference=TIME_REFERENCE.IMAGE) -> Timestamp:
        assert reference == TIME_REFERENCE.IMAGE
        return Timestamp(stamp_ns(self.seq, self.fps))

    def close(self) -> None:
        self.closed = True


def image(resolution: RESOLUTION, seq: int) -> np.ndarray:
    """``VIEW.LEFT`` of frame ``seq``: (H, W, 4) BGRA uint8."""
    w, h = SIZES[resolution]
    out = np.empty((h, w, 4), np.uint8)
    out[..., 0] = (np.arange(w) % 256)[None, :]
    out[..., 1] = (np.arange(h) % 256)[:, None]
    out[..., 2] = seq % 256
    out[..., 3] = 255
    return out


def xyz_mm(resolution: RESOLUTION, seq: int) -> np.ndarray:
    """``MEASURE.XYZ`` of frame ``seq`` in IMAGE coordinates: (H, W, 4) float32 [mm]."""
    w, h = SIZES[resolution]
    f = FOCAL[resolution]
    z = depth_mm(seq)
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    out = np.zeros((h, w, 4), np.float32)
    out[..., 0] = (u - (w - 1) / 2.0) * z / f
    out[..., 1] = (v - (h - 1) / 2.0) * z / f
    out[..., 2] = z
    flat = out.reshape(-1, 4)
    flat[::7, :3] = np.nan
    flat[5::11, :3] = np.inf
    return out
