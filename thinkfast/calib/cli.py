"""``thinkfast-calib``: camera pose and arm dynamics of a real cell (docs/CALIBRATION.md)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import typer

from thinkfast.cli_util import make_app, run_app

app = make_app("Calibrate a cell: camera pose in base, controller lag and the arm's limits.")

ROBOT = typer.Option(
    None, "--robot", help="robot.toml (default: the --tree's robot, else the package's default)"
)
TREE = typer.Option(
    None, "--tree", help="the cell's tree: its robot (and home); --robot must then be the same"
)


def _robot(robot: Path | None, tree: Path | None):
    """The robot to calibrate, in ``base`` (calibration works in the robot's own frame): the
    tree's (checked, with its home) when ``tree`` is given, else robot.toml at ``robot``.

    Raises:
        ConfigError, RobotModelError, TreeFileError: a bad file, or a robot not the tree's.
    """
    if tree is not None:
        from thinkfast.tree.file import load_meta
        from thinkfast.tree.robot_match import robot_for_tree

        return robot_for_tree(load_meta(tree), str(tree), robot, placed=False)
    from thinkfast.robot.model import load_robot

    return load_robot(robot)


CAMERA_CONFIG = typer.Option(
    None, "--camera-config", help="run or detect config whose [camera] is the assumed pose"
)


@app.callback()
def _group() -> None:
    """Calibrate a cell: camera pose in base, controller lag and the arm's limits."""


def _assumed_camera(path: Path | None):
    """The ``[camera]`` of a run config (or a detect config / camera file), else the default."""
    from thinkfast.config import from_dict, include_table, load_toml
    from thinkfast.contract.camera_mode import CameraSetup

    if path is None:
        return CameraSetup()
    data = include_table(load_toml(path), path, "camera_file", "camera", CameraSetup)
    return from_dict(CameraSetup, data.get("camera", {}), str(path), "camera")


@app.command()
def poses(
    output: Path = typer.Option(..., "-o", "--output", help="pose file to write (JSON)"),
    count: int = typer.Option(12, "--count", help="poses to pick (12 recommended, >= 6)"),
    seed: int = typer.Option(1, "--seed", help="seed of the random configurations"),
    samples: int = typer.Option(200_000, "--samples", help="random configurations drawn"),
    robot: Path | None = ROBOT,
    tree: Path | None = TREE,
    camera_config: Path | None = CAMERA_CONFIG,
) -> None:
    """Pick well-spread, collision-free poses whose shield-mounted ball the camera sees."""
    from thinkfast.calib.camera_sim import pick_poses
    from thinkfast.errors import ConfigError

    if count < 3:
        raise ConfigError("--count", None, f"must be >= 3, got {count}")
    rob = _robot(robot, tree)
    ps = pick_poses(rob, _assumed_camera(camera_config), count, seed, samples)
    doc = {
        "format": "thinkfast-calib-poses",
        "version": 1,
        "robot": rob.name,
        "q": [[round(float(x), 6) for x in q] for q in ps.q],
    }
    output.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    print("pose  joints [deg]                                        ball in camera [m]  facing")
    for i, (q, p, f) in enumerate(zip(ps.q, ps.ball_camera, ps.facing, strict=True)):
        qd = " ".join(f"{v:7.1f}" for v in np.degrees(q))
        print(f"{i:4d}  {qd}  {p[0]:5.2f} {p[1]:5.2f} {p[2]:5.2f}  {f:5.2f}")
    print(f"wrote {output} ({len(ps.q)} poses)")


def _read_poses(path: Path) -> np.ndarray:
    """Joint angles (P, 6) of a pose file written by ``poses``."""
    from thinkfast.errors import ConfigError

    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        q = np.array(doc["q"], dtype=float)
    except FileNotFoundError:
        raise ConfigError(str(path), None, "file not found") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(str(path), "q", f"not a pose file ({type(exc).__name__})") from None
    if q.ndim != 2 or q.shape[1] != 6 or not np.isfinite(q).all():
        raise ConfigError(str(path), "q", f"expected a list of 6 joint angles, got {q.shape}")
    return q


@app.command("simulate-camera")
def simulate_camera(
    output: Path = typer.Option(..., "-o", "--output", help="calibration record (JSON lines)"),
    pose_file: Path = typer.Option(..., "--poses", help="pose file (thinkfast-calib poses)"),
    xyz: tuple[float, float, float] = typer.Option(
        (0.46, 0.0, 0.30), "--xyz", help="true camera origin in base [m]"
    ),
    rpy: tuple[float, float, float] = typer.Option(
        (0.0, 0.0, 0.0), "--rpy", help="true camera roll, pitch, yaw [rad]"
    ),
    seed: int = typer.Option(1, "--seed", help="seed of the camera noise"),
    frames: int = typer.Option(25, "--frames", help="frames per pose (50 Hz)"),
    robot: Path | None = ROBOT,
    tree: Path | None = TREE,
) -> None:
    """Simulate a calibration record: the ZED noise model at a known camera pose."""
    from thinkfast.calib.camera_record import write_camera_record
    from thinkfast.calib.camera_sim import simulate_camera_record
    from thinkfast.config import from_dict
    from thinkfast.contract.frames import CameraExtrinsic

    truth = from_dict(CameraExtrinsic, {"xyz": list(xyz), "rpy": list(rpy)}, "--xyz/--rpy")
    rob = _robot(robot, tree)
    rec = simulate_camera_record(
        rob, _read_poses(pose_file), truth, np.random.default_rng(seed), frames=frames
    )
    header = {"robot": rob.name, "truth": {"xyz": list(xyz), "rpy": list(rpy)}, "seed": seed}
    write_camera_record(output, header, rec)
    n = sum(len(p.positions) for p in rec)
    print(f"wrote {output} ({len(rec)} poses, {n} detections)")


@app.command()
def camera(
    record: Path = typer.Argument(..., help="calibration record (JSON lines)"),
    output: Path = typer.Option(..., "-o", "--output", help="camera file to write (TOML)"),
    fit_ball_offset: bool = typer.Option(
        False, "--fit-ball-offset", help="fit the ball's mount offset on the shield too"
    ),
    robot: Path | None = ROBOT,
    tree: Path | None = TREE,
    camera_id: str | None = typer.Option(
        None,
        "--camera",
        help="another camera than the default one (docs/CAMERAS.md): write a [[cameras]] table "
        "with this id, to paste into the run config",
    ),
) -> None:
    """Fit the camera pose in base; write it as a [camera] table (camera_file = OUTPUT), or with
    --camera ID as a [[cameras]] table with that id."""
    from thinkfast.calib.camera_fit import camera_toml, fit_camera, fit_report
    from thinkfast.calib.camera_record import read_camera_record
    from thinkfast.contract.detection import CAMERA_ID
    from thinkfast.errors import ConfigError

    if camera_id is not None and (camera_id == "base" or not CAMERA_ID.fullmatch(camera_id)):
        raise ConfigError("--camera", None, f"{camera_id!r}: not base; 1-64 of A-Z a-z 0-9 _ . -")
    rec = read_camera_record(record)
    fit = fit_camera(rec.poses, _robot(robot, tree), fit_offset=fit_ball_offset)
    print(fit_report(fit, str(record)))
    truth = rec.header.get("truth")
    if isinstance(truth, dict):
        print(_truth_line(fit, truth))
    output.write_text(camera_toml(fit, str(record), camera_id), encoding="utf-8")
    print(f"wrote {output}")


def _truth_line(fit, truth: dict) -> str:
    """Position and angle error against a simulated record's true pose."""
    from thinkfast.contract.frames import rotation_from_rpy

    dp = np.linalg.norm(fit.xyz - np.array(truth["xyz"], dtype=float))
    Rt = rotation_from_rpy(truth["rpy"])
    ang = np.arccos(np.clip((np.trace(Rt.T @ fit.R) - 1.0) / 2.0, -1.0, 1.0))
    return (
        f"against the record's truth: position {1e3 * dp:.2f} mm, angle {np.degrees(ang):.3f} deg"
    )


@app.command("simulate-dynamics")
def simulate_dynamics(
    output: Path = typer.Option(..., "-o", "--output", help="flight record to write (HDF5)"),
    seed: int = typer.Option(1, "--seed", help="seed of the feedback noise"),
    servo: Path | None = typer.Option(
        None, "--servo", help="TOML of ServoConfig keys (delay, lowpass_hz, a_max, ...)"
    ),
    hard: float = typer.Option(1.6, "--hard", help="hard moves: this times the robot's limits"),
    speed_scale: float = typer.Option(
        1.0, "--speed-scale", help="excitation within the robot's limits times this"
    ),
    stalls: float = typer.Option(
        0.0, "--stalls", help="mean receive delay of a loaded host [s] (0: none)"
    ),
    robot: Path | None = ROBOT,
    tree: Path | None = TREE,
) -> None:
    """Simulate a dynamics record: an excitation through the simulated controller."""
    from thinkfast.calib.dynamics_sim import servo_lag, simulate_dynamics_record
    from thinkfast.config import from_dict, load_toml
    from thinkfast.errors import ConfigError
    from thinkfast.sim.controller import ServoConfig

    cfg = ServoConfig() if servo is None else from_dict(ServoConfig, load_toml(servo), str(servo))
    if not 0.0 < speed_scale <= 1.0 or stalls < 0.0:
        raise ConfigError("--speed-scale/--stalls", None, "speed scale in (0, 1], stalls >= 0")
    n = simulate_dynamics_record(
        output, _robot(robot, tree), cfg, seed, hard=hard, speed_scale=speed_scale, stalls=stalls
    )
    print(
        f"wrote {output} ({n} egm rows); servo lag {1e3 * servo_lag(cfg):.1f} ms, "
        f"a_max {list(cfg.a_max)} rad/s^2"
    )


@app.command()
def dynamics(
    record: Path = typer.Argument(..., help="flight record (thinkfast-run --record)"),
    output: Path = typer.Option(..., "-o", "--output", help="run config patch to write (TOML)"),
    robot: Path | None = ROBOT,
    tree: Path | None = TREE,
    cycle: float | None = typer.Option(
        None, "--cycle", help="controller cycle [s] (default: the record's safety.dt, 4 ms)"
    ),
) -> None:
    """Estimate the controller lag and the acceleration and jerk the arm achieves, on the
    controller's clock; only limits the record approached are measured."""
    from thinkfast.calib.dynamics import estimate_from_record
    from thinkfast.calib.dynamics_report import dynamics_patch, dynamics_report, limit_verdicts

    rob = _robot(robot, tree)
    est = estimate_from_record(str(record), cycle=cycle)
    verdicts = limit_verdicts(est, rob.a_max, rob.j_max)
    print(dynamics_report(est, str(record), verdicts))
    output.write_text(dynamics_patch(est, str(record), verdicts, str(rob.toml_path)), "utf-8")
    print(f"wrote {output}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    sys.exit(run_app(app, "thinkfast-calib", argv))


if __name__ == "__main__":
    main()
