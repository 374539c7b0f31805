"""Columns of a flight record read back as named arrays, for the record tools (view, MCAP, plot).

:func:`~thinkfast.record.format.read_record` gives the streams as float tables
(docs/RECORD_FORMAT.md); :func:`columns` slices them by the column names of
:data:`~thinkfast.record.format.STREAMS`, and :func:`raw_positions` parses the raw
payloads into ``base`` with the camera extrinsic of the run configuration the record holds.
"""

from __future__ import annotations

import json
from typing import NamedTuple

import numpy as np

from thinkfast.record.format import STREAM, Record


def column_slices(stream: str) -> dict[str, slice]:
    """Column name -> slice of the table of ``stream`` (``x[n]`` is n columns)."""
    out, i = {}, 0
    for name in STREAM[stream].columns.split():
        n = 1
        if name.endswith("]"):
            name, n = name[: name.index("[")], int(name[name.index("[") + 1 : -1])
        out[name] = slice(i, i + n)
        i += n
    return out


def columns(record: Record, stream: str) -> dict[str, np.ndarray]:
    """The table of ``stream`` as named columns: (N,) for one column, (N, n) for ``x[n]``."""
    table = record.tables[stream]
    out = {}
    for name, s in column_slices(stream).items():
        out[name] = table[:, s] if s.stop - s.start > 1 else table[:, s.start]
    return out


def run_config(record: Record):
    """The record's run configuration (RunConfig); the defaults when it holds none.

    Raises:
        ConfigError: the stored configuration does not validate (names the key).
    """
    from thinkfast.config import from_dict
    from thinkfast.control.config import RunConfig

    text = record.attrs.get("run_config")
    if not text:
        return RunConfig()
    data = json.loads(text) if isinstance(text, str) else text
    return from_dict(RunConfig, data, f"{record.path}: run_config")


class RawPoints(NamedTuple):
    """Raw payloads that parse as detections: receive time [s] (N,), position in base [m]
    (N, 3)."""

    t: np.ndarray
    position: np.ndarray


def plane_json(plane) -> str:
    """A :class:`~thinkfast.contract.frames.PlanePose` (or None: ``base``) as a record's
    ``plane`` attribute: JSON ``{"distance", "yaw", "offset", "base_height"}``, or ``""``."""
    return "" if plane is None else json.dumps(plane.as_dict())


def record_plane(record: Record):
    """The plane whose frame the record's estimates are in (its ``plane`` attribute), or None
    for ``base`` (a record without one, or of a plane without a pose).

    Raises:
        ValueError, KeyError: the attribute is not the JSON :func:`plane_json` writes.
    """
    from thinkfast.contract.frames import PlanePose

    text = record.attrs.get("plane") or ""
    if not text:
        return None
    plane = PlanePose.from_dict(json.loads(text))
    return None if plane.identity else plane


def raw_positions(record: Record, cfg) -> RawPoints:
    """Every raw payload that parses as a detection, moved into ``base`` with ``cfg.camera``,
    then into the plane's frame where the record's plane has a pose (:func:`record_plane`:
    the frame of its estimates)."""
    from thinkfast.contract.detection import parse_detection
    from thinkfast.contract.frames import PlanePose, to_base

    R, p = cfg.camera.rotation(), cfg.camera.translation()
    plane = record_plane(record) or PlanePose()
    t, pos = [], []
    for ti, payload in zip(record.raw_t, record.raw_payloads, strict=True):
        det = parse_detection(payload, cfg.detections)
        if hasattr(det, "position"):
            t.append(ti)
            pos.append(plane.to_plane(to_base(det, R, p).position))
    return RawPoints(np.array(t, dtype=float), np.array(pos, dtype=float).reshape(-1, 3))


def plane_x(record: Record) -> float | None:
    """The blocking plane's x [m], from the beliefs that cross it (x + vx tau at the mean);
    None when no belief does."""
    b = columns(record, "beliefs")
    ok = b["crossing_ok"] > 0.5
    if not np.any(ok):
        return None
    x = b["mean"][ok, 0] + b["mean"][ok, 3] * b["o_mean"][ok, 2]
    return float(np.median(x))


def event_times(record: Record) -> np.ndarray:
    """Times [s] of the record's events, each non-finite one (an event before the controller's
    clock started) replaced by the previous finite time, or the run's start."""
    last = record.attrs.get("started")
    last = float(last) if isinstance(last, int | float) else 0.0
    out = np.empty(len(record.events))
    for i, ev in enumerate(record.events):
        if np.isfinite(ev.t):
            last = ev.t
        out[i] = last
    return out


def break_at_gaps(t: np.ndarray, *ys: np.ndarray, gap: float) -> tuple[np.ndarray, ...]:
    """``t`` (N,) and each ``y`` (N, ...) with a NaN row inserted wherever consecutive times are
    more than ``gap`` [s] apart, so a plotted line (or step) stops at the gap instead of
    bridging it (a state held through an idle stretch, a line from one throw to the next)."""
    t = np.asarray(t, dtype=float)
    at = np.flatnonzero(np.diff(t) > gap) + 1
    if len(at) == 0:
        return (t, *(np.asarray(y, dtype=float) for y in ys))
    t_out = np.insert(t, at, (t[at - 1] + t[at]) / 2.0)
    out = [t_out]
    for y in ys:
        y = np.asarray(y, dtype=float)
        out.append(np.insert(y, at, np.nan, axis=0))
    return tuple(out)
