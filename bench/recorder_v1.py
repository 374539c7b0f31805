"""The schema-1 flight recorder, kept for ``bench/recorder.py --v1`` to compare against.

Its row methods keep every row as a tuple in a list for the whole run; ``close`` writes the
file at once (temporary file, then rename) in the calling process. Same API as
:class:`thinkfast.record.recorder.Recorder` as far as the bench uses it. Not for use.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

from thinkfast.record.format import MODES, STREAMS

NAMES = {"raw": "raw", "detection": "detections", "belief": "beliefs", "decision": "decisions"}


class V1Recorder:
    """Rows in memory, one HDF5 file written by :meth:`close` (schema 1)."""

    writer_pid = None
    shipped = 0
    in_flight_bytes = 0

    def __init__(self, path: str | Path, attrs: dict):
        self.path, self.attrs = Path(path), attrs
        self.rows: dict[str, list] = {s.name: [] for s in STREAMS if s.name != "events"}

    def raw(self, t, payload) -> None:
        self.rows["raw"].append((t, bytes(payload)))

    def detection(self, t, stamp, p, seq) -> None:
        self.rows["detections"].append((t, stamp, *p, -1 if seq is None else seq))

    def belief(self, t, b, c) -> None:
        row = (t, b.t, *b.mean, *b.cov.ravel(), float(c.ok), *c.mean, *c.cov.ravel())
        self.rows["beliefs"].append(row)

    def decision(self, t, mode, node, value, best_goal) -> None:
        self.rows["decisions"].append((t, MODES.index(mode), node, value, best_goal))

    def egm(self, t, seqno, q_fb, q_cmd, qd_cmd, braking) -> None:
        self.rows["egm"].append((t, seqno, *q_fb, *q_cmd, *qd_cmd, float(braking)))

    def event(self, t, kind, detail) -> None:
        """Schema 1 had no events."""

    def service(self) -> None:
        """Schema 1 had nothing to do between rows."""

    def status(self) -> dict:
        n = sum(len(v) for v in self.rows.values())
        return {"state": "recording", "rows": n, "dropped": 0, "errors": 0, "written": 0}

    def close(self) -> None:
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        with h5py.File(tmp, "w") as f:
            f.attrs["format"], f.attrs["schema_version"] = "thinkfast-record", 1
            for k, v in self.attrs.items():
                f.attrs[k] = v if isinstance(v, str | int | float) else json.dumps(v)
            for s in STREAMS:
                if s.name == "events":
                    continue
                rows = self.rows[s.name]
                if s.name == "raw":
                    obj = f.create_group("raw")
                    obj.create_dataset("t_recv", data=np.array([r[0] for r in rows], float))
                    ds = obj.create_dataset(
                        "payload", (len(rows),), dtype=h5py.vlen_dtype(np.dtype("uint8"))
                    )
                    for i, r in enumerate(rows):
                        ds[i] = np.frombuffer(r[1], dtype=np.uint8)
                else:
                    data = np.array(rows, dtype=float).reshape(len(rows), -1)
                    obj = f.create_dataset(s.name, data=data if rows else np.zeros((0, 0)))
                obj.attrs["columns"], obj.attrs["units"], obj.attrs["doc"] = s[1:4]
        os.replace(tmp, self.path)
