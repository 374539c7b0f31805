"""Camera calibration records (``thinkfast-camera-calib`` version 1, JSON lines).

A ball sits on the shield's face centre; the arm stands still at a set of poses; at each pose the
camera's detections of the ball (in the ``camera`` frame) are recorded. One UTF-8 JSON object per
line (docs/CALIBRATION.md):

* line 1, the header: ``{"format": "thinkfast-camera-calib", "version": 1, ...}``; optional
  ``robot`` (name), ``ball_radius`` [m], ``created`` [s, Unix time], ``truth`` (a simulated
  record's camera pose, ``{"xyz": [...], "rpy": [...]}``); unknown keys are ignored;
* one line per pose: ``{"q": [6 joint angles, rad], "detections": [[stamp, x, y, z], ...]}``
  with ``stamp`` the capture time [s] and ``x y z`` the ball centre in ``camera`` [m]; a pose
  may have no detections (it is reported, not fitted).

Blank lines are skipped. :func:`read_camera_record` refuses anything else with one line naming
the path, the line and the reason.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from thinkfast.errors import CalibRecordError

FORMAT, VERSION = "thinkfast-camera-calib", 1


class CalibPose(NamedTuple):
    """One pose of a calibration record.

    Attributes:
        q: joint angles [rad], shape (6,).
        stamps: capture times of the detections [s], shape (N,).
        positions: ball centre measured in ``camera`` [m], shape (N, 3).
    """

    q: np.ndarray
    stamps: np.ndarray
    positions: np.ndarray


class CameraRecord(NamedTuple):
    """A calibration record: the header (dict) and the poses in file order."""

    header: dict
    poses: list[CalibPose]


def write_camera_record(path: str | Path, header: dict, poses: list[CalibPose]) -> None:
    """Write ``poses`` with ``header`` (format and version are set here) to ``path``."""
    head = {"format": FORMAT, "version": VERSION, **header}
    lines = [json.dumps(head)]
    for p in poses:
        dets = [
            [float(s), *(float(x) for x in xyz)]
            for s, xyz in zip(p.stamps, p.positions, strict=True)
        ]
        lines.append(json.dumps({"q": [float(x) for x in p.q], "detections": dets}))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_camera_record(path: str | Path) -> CameraRecord:
    """Read and validate a calibration record.

    Raises:
        CalibRecordError: unreadable, not this format or version, a malformed pose line, or no
            pose (the message names the path, the line and the reason).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibRecordError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibRecordError(f"{path}: cannot read ({exc})") from None
    header: dict | None = None
    poses: list[CalibPose] = []
    for no, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{path}: line {no}"
        try:
            obj = json.loads(line)
        except ValueError as exc:
            raise CalibRecordError(f"{where}: not JSON ({exc})") from None
        if not isinstance(obj, dict):
            raise CalibRecordError(f"{where}: expected a JSON object")
        if header is None:
            header = _header(obj, where)
        else:
            poses.append(_pose(obj, where))
    if header is None:
        raise CalibRecordError(f"{path}: empty file (expected a {FORMAT} header line)")
    if not poses:
        raise CalibRecordError(f"{path}: no pose lines after the header")
    return CameraRecord(header, poses)


def _header(obj: dict, where: str) -> dict:
    if obj.get("format") != FORMAT:
        raise CalibRecordError(f"{where}: format {obj.get('format')!r} is not {FORMAT!r}")
    if obj.get("version") != VERSION:
        raise CalibRecordError(
            f"{where}: version {obj.get('version')!r} is not supported (this reader knows "
            f"{VERSION})"
        )
    return obj


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _pose(obj: dict, where: str) -> CalibPose:
    q = obj.get("q")
    if not isinstance(q, list) or len(q) != 6 or any(_number(x) is None for x in q):
        raise CalibRecordError(f"{where}: q: expected 6 finite joint angles [rad], got {q!r:.80}")
    if max(abs(float(x)) for x in q) > 4 * math.pi:
        raise CalibRecordError(f"{where}: q: angles beyond 4 pi: radians expected, not degrees")
    dets = obj.get("detections")
    if not isinstance(dets, list):
        raise CalibRecordError(f"{where}: detections: expected an array of [stamp, x, y, z]")
    rows = np.zeros((len(dets), 4))
    for i, d in enumerate(dets):
        vals = [_number(x) for x in d] if isinstance(d, list) and len(d) == 4 else [None]
        if any(v is None for v in vals):
            raise CalibRecordError(
                f"{where}: detections[{i}]: expected [stamp, x, y, z] finite numbers, got {d!r:.80}"
            )
        rows[i] = vals
    if len(rows) and (rows[:, 1] <= 0.0).any():
        raise CalibRecordError(
            f"{where}: detections: depth x <= 0 (positions must be in the camera frame: "
            "x forward, y left, z up)"
        )
    return CalibPose(np.array(q, dtype=float), rows[:, 0].copy(), rows[:, 1:].copy())
