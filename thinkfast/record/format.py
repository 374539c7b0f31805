"""Flight record files (``thinkfast-record``): the streams, and the reader of schema 1 and 2.

docs/RECORD_FORMAT.md describes the file. The writer is :mod:`thinkfast.record.file`
(in the recorder's writer process); :func:`read_record` reads every stream of a file of either
version, :func:`read_detections` only what ``thinkfast-sim replay`` needs. A partial file (the
writer failed or was killed) reads like any other: it holds the rows of the writer's last commit.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import h5py
import numpy as np

from thinkfast.errors import RecordFileError

FORMAT, SCHEMA_VERSION = "thinkfast-record", 2
READABLE_VERSIONS = (1, 2)
MODES = ("idle", "tracking", "executing", "returning", "fault")
RESERVED_ATTRS = ("format", "schema_version", "complete")


class Stream(NamedTuple):
    """One stream of the record.

    Attributes:
        name: dataset (table) or group (variable-length rows) name in the file.
        columns: column names, space separated (``x[n]``: n columns).
        units: units of the columns, comma separated.
        doc: what a row is.
        width: float64 columns of a table; 0 for a group of variable-length rows.
    """

    name: str
    columns: str
    units: str
    doc: str
    width: int


STREAMS = (
    Stream("raw", "t_recv payload", "s, bytes", "every detection payload as received", 0),
    Stream(
        "detections",
        "t_recv stamp x y z seq",
        "s, s, m, m, m, 1",
        "accepted detections in base (seq -1 when absent)",
        6,
    ),
    Stream(
        "beliefs",
        "t stamp mean[6] cov[36] crossing_ok o_mean[3] o_cov[9]",
        "s, s, m and m/s, m^2.., bool, m m s, m^2..",
        "filter belief after each accepted detection and its plane crossing",
        57,
    ),
    Stream(
        "decisions",
        "t mode node value best_goal",
        "s, enum, index, probability, index",
        "planner state: node reached and value of the chosen branch",
        5,
    ),
    Stream(
        "egm",
        "t seqno q_fb[6] q_cmd[6] qd_cmd[6] braking",
        "s, 1, rad, rad, rad/s, bool",
        "every EGM exchange: feedback and the setpoint sent",
        21,
    ),
    Stream(
        "events",
        "t kind detail",
        "s, text, JSON text",
        "what the daemon reports: throws, brakes, EGM peers, recovery (schema 2)",
        0,
    ),
)
STREAM = {s.name: s for s in STREAMS}
TABLES = tuple(s.name for s in STREAMS if s.width)


class Event(NamedTuple):
    """One row of the ``events`` stream: time [s], kind, and the decoded JSON detail."""

    t: float
    kind: str
    detail: object


@dataclass(frozen=True)
class Record:
    """A flight record read into memory.

    Attributes:
        path: the file.
        version: its schema version (1 or 2).
        attrs: the daemon's attributes (planner, run_config, started, ...); schema 2 stores a
            dict, list, bool or None as JSON in ``KEY.json``, returned decoded as ``KEY``.
        complete: True when the writer closed the file; False for a partial record (the writer
            failed or was killed); None for schema 1 (always written whole).
        tables: ``detections`` (N, 6), ``beliefs`` (N, 57), ``decisions`` (N, 5), ``egm``
            (N, 21) float64 arrays (columns in :data:`STREAMS`).
        raw_t: receive times of the raw payloads [s], shape (N,).
        raw_payloads: the raw detection payloads, N byte strings.
        events: the ``events`` stream (empty for schema 1).
    """

    path: Path
    version: int
    attrs: dict
    complete: bool | None
    tables: dict[str, np.ndarray]
    raw_t: np.ndarray
    raw_payloads: list[bytes] = field(repr=False)
    events: list[Event]


def read_record(path: str | Path) -> Record:
    """Read every stream of a record of schema 1 or 2.

    Raises:
        RecordFileError: not readable, not a flight record, an unknown schema version, or a
            stream missing or malformed (the message names the path and the reason).
    """
    path = Path(path)
    with _open(path) as (f, version):
        try:
            tables = {name: _table(f, name) for name in TABLES}
            raw_t, payloads = _raw(f)
            events = _events(f) if version >= 2 else []
            attrs = _attrs(f.attrs)
            complete = bool(f.attrs["complete"]) if version >= 2 else None
        except (KeyError, ValueError, TypeError, OSError) as exc:
            raise RecordFileError(f"{path}: damaged flight record ({_first_line(exc)})") from None
    return Record(path, version, attrs, complete, tables, raw_t, payloads, events)


def read_detections(path: str | Path) -> tuple[np.ndarray, list[bytes]]:
    """Receive times [s] (N,) and raw payloads of a record of schema 1 or 2, for replay.

    Raises:
        RecordFileError: as :func:`read_record`.
    """
    path = Path(path)
    with _open(path) as (f, _):
        try:
            return _raw(f)
        except (KeyError, ValueError, TypeError, OSError) as exc:
            raise RecordFileError(f"{path}: damaged flight record ({_first_line(exc)})") from None


class _open:
    """Context manager: the open file and its schema version, after the format checks."""

    def __init__(self, path: Path):
        self.path = path
        self.f: h5py.File | None = None

    def __enter__(self) -> tuple[h5py.File, int]:
        path = self.path
        try:
            self.f = h5py.File(path, "r")
        except (OSError, ValueError) as exc:
            raise RecordFileError(
                f"{path}: not a readable HDF5 file ({_first_line(exc)})"
            ) from None
        fmt = _attr(self.f.attrs.get("format"))
        if fmt != FORMAT:
            self.f.close()
            raise RecordFileError(f"{path}: format is {fmt!r}, expected {FORMAT!r}")
        version = self.f.attrs.get("schema_version")
        if not isinstance(version, int | np.integer) or int(version) not in READABLE_VERSIONS:
            self.f.close()
            raise RecordFileError(
                f"{path}: schema_version {_attr(version)!r} is not supported (this reader "
                f"knows {', '.join(map(str, READABLE_VERSIONS))}; a newer thinkfast wrote it?)"
            )
        return self.f, int(version)

    def __exit__(self, *exc) -> None:
        if self.f is not None:
            self.f.close()


def _table(f: h5py.File, name: str) -> np.ndarray:
    width = STREAM[name].width
    data = np.asarray(f[name][:], dtype=float)
    if data.size == 0:  # schema 1 writes an empty stream as shape (0, 0)
        return np.zeros((0, width))
    if data.ndim != 2 or data.shape[1] != width:
        raise ValueError(f"{name} has shape {data.shape}, expected (N, {width})")
    return data


def _raw(f: h5py.File) -> tuple[np.ndarray, list[bytes]]:
    t = np.asarray(f["raw/t_recv"][:], dtype=float)
    payloads = [bytes(np.asarray(p, dtype=np.uint8)) for p in f["raw/payload"][:]]
    if len(payloads) != len(t):
        raise ValueError(f"raw has {len(t)} times and {len(payloads)} payloads")
    return t, payloads


def _events(f: h5py.File) -> list[Event]:
    g = f["events"]
    t = np.asarray(g["t"][:], dtype=float)
    kinds = g["kind"].asstr()[:]
    details = g["detail"].asstr()[:]
    if not len(t) == len(kinds) == len(details):
        raise ValueError("events columns differ in length")
    rows = zip(t, kinds, details, strict=True)
    return [Event(float(a), str(k), json.loads(d)) for a, k, d in rows]


def _attrs(attrs) -> dict:
    """The daemon's attributes as plain Python values; ``KEY.json`` ones decoded as ``KEY``."""
    out = {}
    for key, value in attrs.items():
        if key in RESERVED_ATTRS:
            continue
        value = _attr(value)
        if key.endswith(".json") and isinstance(value, str):
            key, value = key[: -len(".json")], json.loads(value)
        out[key] = value
    return out


def _attr(value):
    """An HDF5 attribute value as a plain Python value."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value.item() if isinstance(value, np.generic) else value


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
