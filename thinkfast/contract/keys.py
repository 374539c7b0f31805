"""zenoh key expressions of the contract (docs/INTERFACES.md, "zenoh"), from the key prefix."""

from __future__ import annotations

DEFAULT_PREFIX = "thinkfast"


def detections(prefix: str = DEFAULT_PREFIX) -> str:
    """Ball detections in (JSON, :mod:`thinkfast.contract.detection`)."""
    return f"{prefix}/detections"


def setpoints(prefix: str = DEFAULT_PREFIX) -> str:
    """Mirror of every setpoint sent to the controller (JSON)."""
    return f"{prefix}/setpoints"


def status(prefix: str = DEFAULT_PREFIX) -> str:
    """The daemon's status (JSON, 20 Hz)."""
    return f"{prefix}/status"


def camera_frame(prefix: str = DEFAULT_PREFIX, camera: str | None = None) -> str:
    """Camera frames for ``thinkfast-detect`` (docs/CAMERA_FRAMES.md); another camera than the
    default one (docs/CAMERAS.md) has its own, ``<prefix>/camera/<id>/frame``."""
    return f"{prefix}/camera/frame" if camera is None else f"{prefix}/camera/{camera}/frame"


def camera_boxes(prefix: str = DEFAULT_PREFIX, camera: str | None = None) -> str:
    """Boxes from an external detector (optional; docs/CAMERA_FRAMES.md), per camera as
    :func:`camera_frame`."""
    return f"{prefix}/camera/boxes" if camera is None else f"{prefix}/camera/{camera}/boxes"


def detector_status(prefix: str = DEFAULT_PREFIX) -> str:
    """``thinkfast-detect``'s counters (JSON, 2 Hz)."""
    return f"{prefix}/detector/status"
