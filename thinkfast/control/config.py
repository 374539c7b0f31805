"""Runtime configuration of ``thinkfast-run`` (one TOML file, every table optional).

Defaults describe the default cell; assumed numbers are labelled ASSUMED in the field docs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from thinkfast.config import from_dict, include_table, load_toml, spec, to_toml
from thinkfast.contract.camera_mode import DEFAULT_FPS, CameraSetup, check_camera_setup
from thinkfast.contract.detection import CAMERA_ID, DetectionLimits
from thinkfast.control.hedge import HedgeConfig
from thinkfast.control.safety import SafetyConfig
from thinkfast.control.solver_config import JplConfig, MpcConfig
from thinkfast.decide.choice import ChoiceConfig
from thinkfast.decide.path_value import PathValueConfig
from thinkfast.decide.values import ValueConfig
from thinkfast.errors import ConfigError
from thinkfast.estimate.early_belief import EarlyConfig
from thinkfast.estimate.filter import FilterConfig
from thinkfast.estimate.fusion import DEFAULT_CAMERA, CameraConfig, FusionConfig
from thinkfast.estimate.launch import LaunchConfig
from thinkfast.estimate.retract import RetractConfig


@dataclass(frozen=True)
class EpisodeConfig:
    """When a throw starts and ends."""

    min_approach_speed: float = spec(
        3.0,
        unit="m/s",
        lo=0.0,
        doc="a throw starts when the approach speed exceeds this with confidence "
        "(mean - approach_sigmas sigma), so a ball held still never starts one",
    )
    approach_sigmas: float = spec(
        2.0, unit="sigma", lo=0.0, doc="confidence of the approach-speed test (2: ~98 %)"
    )
    settle_updates: int = spec(
        2,
        lo=0,
        doc="filter updates since its last (re)start before a belief may confirm a throw "
        "(one outlier among the two starting measurements can fake any velocity)",
    )
    max_tau: float = spec(
        1.5, unit="s", lo=0.0, lo_open=True, doc="crossing must be predicted within this time"
    )
    region_margin: float = spec(
        0.6, unit="m", lo=0.0, doc="crossing point may lie this far outside the goal region"
    )
    confirm_updates: int = spec(
        2, lo=1, doc="approaching beliefs (net of non-approaching ones) that start a throw"
    )
    detection_timeout: float = spec(
        0.25,
        unit="s",
        lo=0.0,
        lo_open=True,
        doc="no detection this long ends a throw, unless the arm is executing and the predicted "
        "crossing is still ahead (the ball may leave the camera's view before the plane)",
    )
    max_blind: float = spec(
        1.0,
        unit="s",
        lo=0.0,
        lo_open=True,
        doc="no detection this long ends a throw in execution even with its crossing ahead",
    )
    after_crossing: float = spec(
        0.15, unit="s", lo=0.0, doc="hold the pose this long after the predicted crossing"
    )
    stamp_lag: float = spec(
        0.05,
        unit="s",
        lo=0.0,
        hi=1.0,
        doc="ASSUMED lag of detection stamps behind the clock the executor runs on (capture to "
        "receipt); the silence that ends a throw is counted from the last stamp plus this",
    )


@dataclass(frozen=True)
class ExecutionConfig:
    """How plans become setpoints."""

    controller_lag: float = spec(
        0.04,
        unit="s",
        lo=0.0,
        hi=0.5,
        doc="ASSUMED delay from a setpoint to the arm being there (EGM transport + servo lag; "
        "ABB quotes 10-20 ms, field reports 40-80 ms)",
    )
    min_move_value: float = spec(
        0.02, lo=0.0, hi=1.0, doc="leave home only when the best branch blocks with this chance"
    )
    wrist_max_tilt: float = spec(
        0.5, unit="rad", lo=0.0, hi=1.2, doc="largest tilt of the shield normal away from +x"
    )
    wrist_confident_speed_std: float = spec(
        1.0,
        unit="m/s",
        lo=0.0,
        lo_open=True,
        doc="tilt towards the ball only when the velocity std is below this",
    )
    return_speed_scale: float = spec(
        0.5, lo=0.05, hi=1.0, doc="fraction of the velocity limits used to return home"
    )
    wrist_inner_margin: float = spec(
        0.02,
        unit="rad",
        lo=0.0,
        hi=0.5,
        doc="wrist targets stay this much further inside the limits than the supervisor's "
        "position margin",
    )
    wrist_home_tolerance: float = spec(
        1e-3, unit="rad", lo=0.0, lo_open=True, doc="the wrist is home within this"
    )
    wrist_home_speed: float = spec(
        1e-4, unit="rad/s", lo=0.0, lo_open=True, doc="... and slower than this"
    )
    wrist_home_timeout: float = spec(
        2.0,
        unit="s",
        lo=0.0,
        doc="a return is over this long after the arm is home even if the wrist is not",
    )


@dataclass(frozen=True)
class RunConfig:
    """Everything ``thinkfast-run`` needs besides the tree and the I/O endpoints."""

    robot: str = spec("", doc="robot.toml path (default: the robot the tree names, else default)")
    camera: CameraSetup = spec(CameraSetup())
    cameras: tuple[CameraConfig, ...] = spec(
        (),
        doc="more cameras, [[cameras]] tables (docs/CAMERAS.md); [camera] is the default one, "
        "id base",
    )
    fusion: FusionConfig = spec(FusionConfig())
    detections: DetectionLimits = spec(DetectionLimits())
    filter: FilterConfig = spec(
        FilterConfig(
            stereo_depth=0.0027,
            stereo_lateral=0.00094,
            r0_std=(0.01, 0.01, 0.01),
            reset_after=2,
            reset_all_axes=True,
        )
    )
    launch: LaunchConfig = spec(LaunchConfig())
    retract: RetractConfig = spec(RetractConfig())
    early: EarlyConfig = spec(EarlyConfig())
    hedge: HedgeConfig = spec(HedgeConfig())
    value: ValueConfig = spec(ValueConfig())
    throw: EpisodeConfig = spec(EpisodeConfig())
    execution: ExecutionConfig = spec(ExecutionConfig())
    choice: ChoiceConfig = spec(ChoiceConfig())
    path_value: PathValueConfig = spec(PathValueConfig())
    safety: SafetyConfig = spec(SafetyConfig(position_margin=0.005))
    mpc: MpcConfig = spec(MpcConfig())
    jpl: JplConfig = spec(JplConfig())
    status_rate: float = spec(20.0, unit="Hz", lo=10.0, hi=250.0, doc="status publishing rate")


def load_run_config(path: str | Path | None) -> RunConfig:
    """The runtime configuration from ``path`` (None: all defaults).

    A top-level ``camera_file = "camera.toml"`` takes the ``[camera]`` table from that file
    (``thinkfast-calib camera`` writes it; relative to this file's directory) instead of an
    inline ``[camera]`` table.

    Raises:
        ConfigError: unreadable file, unknown key, wrong type or impossible value (names the key).
    """
    if path is None:
        return RunConfig()
    data = include_table(load_toml(path), path, "camera_file", "camera", CameraSetup)
    cfg = from_dict(RunConfig, data, str(path))
    check_camera_setup(cfg.camera, str(path))
    return check_lags(check_cameras(cfg, str(path)), str(path))


def default_camera_filter(cfg: RunConfig) -> FilterConfig:
    """The filter parameters for the default camera (``[camera]``) in its mode.

    ``[filter] stereo_depth`` and ``stereo_lateral`` are stated for HD720; another mode
    measures with the same disparity and pixel noise on coarser pixels, so both are scaled by
    ``f_HD720 / f`` (VGA: about 2). HD720 returns ``cfg.filter`` itself.
    """
    scale = cfg.camera.focal_scale()
    if scale == 1.0:
        return cfg.filter
    f = cfg.filter
    return dataclasses.replace(
        f, stereo_depth=f.stereo_depth * scale, stereo_lateral=f.stereo_lateral * scale
    )


def launch_window(cfg: RunConfig) -> int:
    """Detections per launch fit of the default camera alone, at its frame rate.

    ``[launch] window`` is stated at 50 fps (6: 100 ms); at another ``[camera] fps`` the fit
    keeps that time span, ``1 + round((window - 1) fps / 50)`` detections within 4..12 (VGA at
    100 fps: 11). At 50 fps it is ``[launch] window`` itself.
    """
    w = cfg.launch.window
    return min(max(1 + round((w - 1) * cfg.camera.fps / DEFAULT_FPS), 4), 12)


def early_config(cfg: RunConfig) -> EarlyConfig:
    """The early belief's parameters: ``[early]``; with several cameras fused, its
    ``max_drop``, ``prior_age`` and ``depart_lateral`` are ``[fusion] early_max_drop``,
    ``early_prior_age`` and ``early_depart_lateral`` (as ``[fusion] launch_window`` takes the
    place of ``[launch] window``)."""
    if not cfg.cameras:
        return cfg.early
    f = cfg.fusion
    return dataclasses.replace(
        cfg.early,
        max_drop=f.early_max_drop,
        prior_age=f.early_prior_age,
        depart_lateral=f.early_depart_lateral,
    )


def check_lags(cfg: RunConfig, source: str) -> RunConfig:
    """``cfg`` once the supervisor's ``safety.tracking_lag`` (how far the arm may trail its
    command) is at least ``execution.controller_lag`` (how far it does).

    Raises:
        ConfigError: names ``safety.tracking_lag`` and the fix.
    """
    lag, track = cfg.execution.controller_lag, cfg.safety.tracking_lag
    if track < lag:
        raise ConfigError(
            source, "safety.tracking_lag",
            f"{track:g} s is below execution.controller_lag ({lag:g} s): the supervisor would "
            f"brake an arm that follows as assumed; raise it above {lag:g} s (default 0.2)",
        )  # fmt: skip
    return cfg


def check_cameras(cfg: RunConfig, source: str) -> RunConfig:
    """``cfg`` once its camera ids are distinct, none is the default camera's and (with any)
    the fusion reference is one of them.

    Raises:
        ConfigError: names the ``cameras[i].id`` or ``fusion.reference`` key.
    """
    seen = {DEFAULT_CAMERA}
    for i, cam in enumerate(cfg.cameras):
        if not CAMERA_ID.fullmatch(cam.id):
            raise ConfigError(source, f"cameras[{i}].id", f"{cam.id!r}: 1-64 of A-Z a-z 0-9 _ . -")
        if cam.id in seen:
            what = "the default camera's ([camera])" if cam.id == DEFAULT_CAMERA else "taken"
            raise ConfigError(source, f"cameras[{i}].id", f"{cam.id!r} is {what}")
        seen.add(cam.id)
    if cfg.fusion.check_fail > cfg.fusion.check_window:
        raise ConfigError(
            source, "fusion.check_fail", f"above fusion.check_window ({cfg.fusion.check_window})"
        )
    if cfg.cameras and cfg.fusion.reference not in seen:  # [fusion] is unused without them
        raise ConfigError(
            source, "fusion.reference", f"{cfg.fusion.reference!r} is not one of {sorted(seen)}"
        )
    return cfg


RUN_CONFIG_TITLE = """thinkfast-run configuration (--config FILE): every key at its default.
Generated by `thinkfast-run --print-config` from the config classes (thinkfast/control/config.py):
each key's meaning above it; unit and bounds after it. SI units, radians. ASSUMED marks a number
that is an assumption until measured on the real cell. A file names only what it changes: every
key it leaves out keeps the default shown here."""


def run_config_toml(cfg: RunConfig | None = None) -> str:
    """``cfg`` (None: the defaults) as commented TOML that :func:`load_run_config` reads back."""
    return to_toml(RunConfig() if cfg is None else cfg, RUN_CONFIG_TITLE)
