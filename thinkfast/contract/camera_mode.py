"""The ZED 2i's video mode: resolution (hence focal length) and frame rate.

One table shared by the run configuration (the daemon's stereo noise model and frame interval),
the detector's configuration and the simulated camera, so that all three describe the same
camera. A mode trades resolution for frame rate: HD720 runs up to 60 fps with f about 532 px,
VGA up to 100 fps with f about 265 px (docs/FACTS.md). At the same disparity noise the depth
noise ``z^2 sigma_d / (f B)`` and the lateral noise ``z sigma_px / f`` grow as ``1 / f``: VGA
measures every frame about twice as coarsely, twice as often. docs/CAMERAS.md says which to run.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

from thinkfast.config import spec
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.errors import ConfigError


class CameraMode(NamedTuple):
    """One video mode of the ZED 2i.

    Attributes:
        name: the ZED SDK's resolution name.
        focal_px: focal length of the rectified left image [px].
        image_size: image width, height [px].
        max_fps: highest frame rate the mode runs at [Hz].
    """

    name: str
    focal_px: float
    image_size: tuple[int, int]
    max_fps: float


# docs/FACTS.md (ZED 2i data sheet): focal lengths are the rectified left camera's, about.
ZED_MODES = {
    "HD720": CameraMode("HD720", 532.0, (1280, 720), 60.0),
    "VGA": CameraMode("VGA", 265.0, (672, 376), 100.0),
}
DEFAULT_MODE = "HD720"  # the mode every stereo figure of the configs is stated for
DEFAULT_FPS = 50.0  # Hz: the paper's system; the frame-count settings were tuned at this rate


@dataclasses.dataclass(frozen=True)
class CameraSetup(CameraExtrinsic):
    """The default camera (``[camera]``): its pose in ``base`` and the mode it runs in."""

    mode: str = spec(
        DEFAULT_MODE,
        choices=tuple(ZED_MODES),
        doc="ZED 2i video mode: HD720 (f 532 px, up to 60 fps) or VGA (f 265 px, up to 100 fps, "
        "about twice the noise in metres); the daemon scales [filter] stereo_depth and "
        "stereo_lateral, stated for HD720, by 532 / f (docs/CAMERAS.md, camera mode)",
    )
    fps: float = spec(
        DEFAULT_FPS,
        unit="Hz",
        lo=0.0,
        lo_open=True,
        doc="frame rate the camera runs at (at most the mode's: HD720 60, VGA 100); 50 is the "
        "paper's system. [launch] window, stated at 50 fps, keeps its time span at this rate",
    )

    def camera_mode(self) -> CameraMode:
        """The mode's figures."""
        return ZED_MODES[self.mode]

    def frame_interval(self) -> float:
        """Time between two frames [s]."""
        return 1.0 / self.fps

    def focal_scale(self) -> float:
        """How much coarser than at HD720 a pixel of error is in metres: ``f_HD720 / f``."""
        return ZED_MODES[DEFAULT_MODE].focal_px / self.camera_mode().focal_px


def check_camera_setup(cam: CameraSetup, source: str, key: str = "camera") -> CameraSetup:
    """``cam`` once its frame rate is one its mode runs at.

    Raises:
        ConfigError: names ``<key>.fps`` (or ``<key>.mode`` for a mode not in the table).
    """
    mode = ZED_MODES.get(cam.mode)
    if mode is None:
        raise ConfigError(
            source, f"{key}.mode", f"{cam.mode!r} is not one of {', '.join(ZED_MODES)}"
        )
    if cam.fps > mode.max_fps:
        faster = [m.name for m in ZED_MODES.values() if m.max_fps >= cam.fps]
        hint = f" ({', '.join(faster)} runs at {cam.fps:g})" if faster else ""
        raise ConfigError(
            source, f"{key}.fps",
            f"{cam.fps:g} fps: {mode.name} runs at most {mode.max_fps:g} fps{hint}",
        )  # fmt: skip
    return cam
