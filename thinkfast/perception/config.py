"""Configuration of ``thinkfast-detect`` (one TOML file, every table optional).

Defaults fit a tennis ball (67 mm, optic yellow) seen by a ZED 2i at HD720; the colour range and
the shrink curve are ASSUMPTIONS to tune on the real camera (docs/CAMERA_FRAMES.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from thinkfast.config import from_dict, include_table, load_toml, spec, to_toml
from thinkfast.contract.camera_mode import CameraSetup, check_camera_setup
from thinkfast.contract.detection import CAMERA_ID
from thinkfast.errors import ConfigError

SOURCES = ("colour", "boxes", "auto")


@dataclass(frozen=True)
class ColourConfig:
    """HSV colour filter plus morphology (OpenCV HSV: H 0-179, S and V 0-255)."""

    hsv_low: tuple[int, int, int] = spec(
        (25, 90, 60), doc="lowest H, S, V of a ball pixel (optic yellow: H about 35)", length=3,
        lo=0, hi=255,
    )  # fmt: skip
    hsv_high: tuple[int, int, int] = spec(
        (45, 255, 255), doc="highest H, S, V of a ball pixel", length=3, lo=0, hi=255
    )
    search_step: int = spec(
        2, doc="coarse search on every n-th pixel (finds balls of radius >= n / sqrt 2 px)",
        lo=1, hi=8,
    )  # fmt: skip
    open_px: int = spec(2, doc="opening kernel (removes specks); 1: none", unit="px", lo=1, hi=15)
    close_px: int = spec(3, doc="closing kernel (fills holes); 1: none", unit="px", lo=1, hi=31)
    min_area: int = spec(4, doc="smallest blob kept after morphology", unit="px", lo=1)
    max_candidates: int = spec(4, doc="coarse blobs examined per frame, largest first", lo=1)


@dataclass(frozen=True)
class ShrinkConfig:
    """Box shrink (the paper's rule): a sigmoid of log10(box area / image area).

    ``shrink = far + (near - far) / (1 + exp(-(log10(a) - log10(mid_area)) / width))``; each side
    of the box is scaled by ``1 - shrink`` about its centre. Defaults: about 5 % at 7-8 m, 28 %
    at 0.5-1 m, where the box's corners (outside the ball's disc) would reach the background.
    """

    far: float = spec(0.04, doc="shrink of a tiny (far) box", lo=0.0, hi=0.9)
    near: float = spec(0.30, doc="shrink of a large (near) box", lo=0.0, hi=0.9)
    mid_area: float = spec(
        3e-4, doc="box area / image area at mid shrink (about 2 m for a 67 mm ball at HD720)",
        lo=0.0, lo_open=True, hi=1.0,
    )  # fmt: skip
    width: float = spec(0.35, doc="sigmoid width", unit="decade", lo=0.0, lo_open=True)


@dataclass(frozen=True)
class CloudConfig:
    """Robust 3-D centre from the point-cloud pixels inside the shrunk box, on the viewing ray
    of the blob's centroid (colour) or the box centre (external boxes)."""

    ball_radius: float = spec(0.0335, doc="ball radius", unit="m", lo=0.0, lo_open=True)
    min_valid: int = spec(3, doc="fewest finite XYZ pixels for a detection", lo=1)
    gate_sigmas: float = spec(3.0, doc="inlier gate half-width in stereo depth noise stds", lo=0.5)
    disparity_sigma: float = spec(
        0.25, doc="stereo disparity noise std assumed for the gate (ZED 2i: 0.1-0.25)", unit="px",
        lo=0.0,
    )  # fmt: skip
    baseline: float = spec(0.12, doc="stereo baseline (ZED 2i)", unit="m", lo=0.0, lo_open=True)
    min_gate: float = spec(
        0.05, doc="inlier gate half-width never below this", unit="m", lo=0.0, lo_open=True
    )
    min_group: int = spec(2, doc="fewest points of the ball's depth group", lo=1)
    group_fraction: float = spec(
        0.3, doc="the ball's group has at least this fraction of the largest group's points",
        lo=0.0, hi=1.0,
    )  # fmt: skip
    min_range: float = spec(0.3, doc="nearest depth accepted (ZED 2i)", unit="m", lo=0.0)
    max_range: float = spec(20.0, doc="farthest depth accepted (ZED 2i)", unit="m", lo=0.0)
    size_ratio: tuple[float, float] = spec(
        (0.5, 2.5), doc="colour blob diameter / expected ball diameter at its depth (blur widens)",
        length=2, lo=0.0,
    )  # fmt: skip
    count_half: float = spec(
        6.0, doc="inlier pixels at which the count factor of the confidence is 0.5", lo=0.0,
        lo_open=True,
    )  # fmt: skip
    spread_half: float = spec(
        0.25, doc="robust range spread at which the spread factor is 0.5", unit="m", lo=0.0,
        lo_open=True,
    )  # fmt: skip


@dataclass(frozen=True)
class BoxConfig:
    """External 2-D boxes (``<prefix>/camera/boxes``)."""

    wait: float = spec(0.05, doc="hold a frame this long for its boxes", unit="s", lo=0.0, hi=1.0)
    min_score: float = spec(0.3, doc="lowest box score used", lo=0.0, hi=1.0)
    label: str = spec("", doc="use only boxes with this label ('': any)")


ZED_DEPTH_MODES = ("PERFORMANCE", "QUALITY", "ULTRA", "NEURAL", "NEURAL_PLUS")


@dataclass(frozen=True)
class ZedConfig:
    """The ZED bridge (``thinkfast-zed``): what it asks of the SDK and how it packs a frame.

    Resolution and frame rate are ``[camera] mode`` and ``fps`` (the same keys as the detector's
    and the run config's); this table holds what only the bridge needs.
    """

    depth_mode: str = spec(
        "NEURAL", doc="the SDK's sl.DEPTH_MODE (ASSUMED: NEURAL, the SDK 4.x recommendation)",
        choices=ZED_DEPTH_MODES,
    )  # fmt: skip
    xyz_step: int = spec(
        0, doc="send the XYZ image at 1/n of the image resolution; 0: 2 at HD720, 1 at VGA "
        "(docs/CAMERA_FRAMES.md, the recommended 4.1 MB a frame)", lo=0, hi=8,
    )  # fmt: skip
    xyz_dtype: str = spec("float16", doc="XYZ samples sent", choices=("float16", "float32"))
    stamp_lag: float = spec(
        0.0, doc="subtracted from the SDK's image timestamp (host reception) to give the capture "
        "time; 0 until measured (docs/FACTS.md: tens of ms)", unit="s", lo=0.0, hi=1.0,
    )  # fmt: skip


@dataclass(frozen=True)
class DetectConfig:
    """Everything ``thinkfast-detect`` needs besides its zenoh endpoints."""

    frame: str = spec("camera", doc="frame of published detections", choices=("camera", "base"))
    source: str = spec(
        "colour", doc="colour filter, external boxes, or boxes when they come (auto)",
        choices=SOURCES,
    )  # fmt: skip
    camera: CameraSetup = spec(CameraSetup())
    camera_id: str = spec(
        "",
        doc="id of the camera this process serves, stamped on every detection, whose frames "
        "come on <prefix>/camera/<id>/frame (docs/CAMERAS.md); empty: the default camera",
    )
    colour: ColourConfig = spec(ColourConfig())
    shrink: ShrinkConfig = spec(ShrinkConfig())
    cloud: CloudConfig = spec(CloudConfig())
    boxes: BoxConfig = spec(BoxConfig())
    zed: ZedConfig = spec(ZedConfig())
    max_frame_bytes: int = spec(64 << 20, doc="largest frame payload", unit="byte", lo=64)
    status_rate: float = spec(2.0, doc="status publishing rate", unit="Hz", lo=0.1, hi=50.0)


def check(cfg: DetectConfig, source: str) -> DetectConfig:
    """Cross-field checks :func:`~thinkfast.config.from_dict` cannot make (names the key)."""
    lo, hi = cfg.colour.hsv_low, cfg.colour.hsv_high
    if any(a > b for a, b in zip(lo, hi, strict=True)):
        raise ConfigError(source, "colour.hsv_low", f"{lo} above colour.hsv_high {hi}")
    if hi[0] > 179:
        raise ConfigError(source, "colour.hsv_high", f"hue {hi[0]} > 179 (OpenCV hue range)")
    if cfg.cloud.size_ratio[0] > cfg.cloud.size_ratio[1]:
        raise ConfigError(source, "cloud.size_ratio", f"low > high: {cfg.cloud.size_ratio}")
    if cfg.cloud.min_range >= cfg.cloud.max_range:
        raise ConfigError(source, "cloud.min_range", "must be below cloud.max_range")
    if cfg.camera_id and not CAMERA_ID.fullmatch(cfg.camera_id):
        raise ConfigError(source, "camera_id", f"{cfg.camera_id!r}: 1-64 of A-Z a-z 0-9 _ . -")
    check_camera_setup(cfg.camera, source)
    return cfg


def load_detect_config(path: str | Path | None) -> DetectConfig:
    """The detector configuration from ``path`` (None: all defaults).

    ``camera_file = "camera.toml"`` takes ``[camera]`` from that file, as in the run config.

    Raises:
        ConfigError: unreadable file, unknown key, wrong type or impossible value (names the key).
    """
    if path is None:
        return DetectConfig()
    data = include_table(load_toml(path), path, "camera_file", "camera", CameraSetup)
    return check(from_dict(DetectConfig, data, str(path)), str(path))


DETECT_CONFIG_TITLE = """thinkfast-detect configuration (--config FILE): every key at its default.
Generated by `thinkfast-detect --print-config` from the config classes
(thinkfast/perception/config.py): each key's meaning above it; unit and bounds after it. SI units,
radians. The colour range and the shrink curve are ASSUMED until tuned on the real camera. A file
names only what it changes: every key it leaves out keeps the default shown here."""


def detect_config_toml(cfg: DetectConfig | None = None) -> str:
    """``cfg`` (None: the defaults) as commented TOML that :func:`load_detect_config` reads back."""
    return to_toml(DetectConfig() if cfg is None else cfg, DETECT_CONFIG_TITLE)
