"""Flight recorder: every detection (raw and accepted), belief, decision and EGM exchange.

Rows are kept in memory (a throw is a few thousand rows) and written as one HDF5 file at the end
(atomically: temporary file, then rename). Format ``thinkfast-record``, schema version 1; every
dataset carries ``units`` and ``doc``. ``thinkfast-sim replay`` re-publishes its detections.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

FORMAT, SCHEMA_VERSION = "thinkfast-record", 1

STREAMS = {
    "raw": ("t_recv payload", "s, bytes", "every detection payload as received"),
    "detections": (
        "t_recv stamp x y z seq",
        "s, s, m, m, m, 1",
        "accepted detections in base (seq -1 when absent)",
    ),
    "beliefs": (
        "t stamp mean[6] cov[36] crossing_ok o_mean[3] o_cov[9]",
        "s, s, m and m/s, m^2.., bool, m m s, m^2..",
        "filter belief after each accepted detection and its plane crossing",
    ),
    "decisions": (
        "t mode node value best_goal",
        "s, enum, index, probability, index",
        "planner state: node reached and value of the chosen branch",
    ),
    "egm": (
        "t seqno q_fb[6] q_cmd[6] qd_cmd[6] braking",
        "s, 1, rad, rad, rad/s, bool",
        "every EGM exchange: feedback and the setpoint sent",
    ),
}
MODES = ("idle", "tracking", "executing", "returning", "fault")


class Recorder:
    """Collects rows; :meth:`close` writes ``path`` (no-op recorder when ``path`` is None)."""

    def __init__(self, path: str | Path | None, attrs: dict | None = None):
        self.path = Path(path) if path else None
        self.attrs = attrs or {}
        self.rows: dict[str, list] = {k: [] for k in STREAMS}

    @property
    def enabled(self) -> bool:
        return self.path is not None

    def raw(self, t: float, payload: bytes) -> None:
        if self.path:
            self.rows["raw"].append((t, bytes(payload)))

    def detection(self, t: float, stamp: float, p: np.ndarray, seq: int | None) -> None:
        if self.path:
            self.rows["detections"].append((t, stamp, *p, -1 if seq is None else seq))

    def belief(self, t: float, belief, crossing) -> None:
        if self.path:
            self.rows["beliefs"].append(
                (
                    t,
                    belief.t,
                    *belief.mean,
                    *belief.cov.ravel(),
                    float(crossing.ok),
                    *crossing.mean,
                    *crossing.cov.ravel(),
                )
            )

    def decision(self, t: float, mode: str, node: int, value: float, best_goal: int) -> None:
        if self.path:
            self.rows["decisions"].append((t, MODES.index(mode), node, value, best_goal))

    def egm(self, t: float, seqno: int, q_fb, q_cmd, qd_cmd, braking: bool) -> None:
        if self.path:
            self.rows["egm"].append((t, seqno, *q_fb, *q_cmd, *qd_cmd, float(braking)))

    def close(self) -> None:
        """Write the file (atomically)."""
        if not self.path:
            return
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["schema_version"] = SCHEMA_VERSION
            for k, v in self.attrs.items():
                f.attrs[k] = v if isinstance(v, str | int | float) else json.dumps(v)
            for name, (columns, units, doc) in STREAMS.items():
                rows = self.rows[name]
                if name == "raw":
                    g = f.create_group(name)
                    g.create_dataset("t_recv", data=np.array([r[0] for r in rows], float))
                    dt = h5py.vlen_dtype(np.dtype("uint8"))
                    ds = g.create_dataset("payload", (len(rows),), dtype=dt)
                    for i, r in enumerate(rows):
                        ds[i] = np.frombuffer(r[1], dtype=np.uint8)
                    obj = g
                else:
                    obj = f.create_dataset(
                        name,
                        data=np.array(rows, dtype=float).reshape(len(rows), -1)
                        if rows
                        else np.zeros((0, 0)),
                    )
                obj.attrs["columns"] = columns
                obj.attrs["units"] = units
                obj.attrs["doc"] = doc
        os.replace(tmp, self.path)


def read_detections(path: str | Path) -> tuple[np.ndarray, list[bytes]]:
    """Receive times (N,) and raw payloads of a record, for replay."""
    with h5py.File(path, "r") as f:
        if f.attrs.get("format") != FORMAT:
            raise ValueError(f"{path}: not a thinkfast flight record")
        t = f["raw/t_recv"][:]
        payloads = [bytes(np.asarray(p, dtype=np.uint8)) for p in f["raw/payload"][:]]
    return t, payloads
