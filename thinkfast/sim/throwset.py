"""Throw-set files (``docs/THROW_SET_FORMAT.md``): the throws themselves, to repeat runs exactly.

Version 2 records each throw's ``kind`` and, for wind-ups and feints, its swing; version 1 files
(no kinds) still load, every throw as ``still``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from thinkfast.config import from_dict, to_dict
from thinkfast.errors import ThinkfastError
from thinkfast.sim.thrower import STILL_MIX, check_motion
from thinkfast.sim.throws import Throw, ThrowConfig

FORMAT = "thinkfast-throws"
VERSION = 2
READS = (1, 2)
"""Versions this reader knows."""
_ARRAYS = {"p_release": 3, "v_release": 3, "aim": 2, "hand_amp": 3, "hand_freq": 3,
           "hand_phase": 3, "back_swing": 3, "back_sag": 3, "forward_swing": 3}  # fmt: skip
_SWING = ("back_time", "back_swing", "back_sag", "forward_time", "forward_swing", "rest_time")
"""Fields written only for wind-ups and feints (a still throw's are 0)."""


def save_throw_set(path: str | Path, throws: list[Throw], cfg: ThrowConfig) -> None:
    """Write ``throws`` and the config that drew them as a JSON throw-set file (version 2)."""
    records = []
    for t in throws:
        rec = {f: (v.tolist() if f in _ARRAYS else v) for f, v in t._asdict().items()}
        if t.kind == "still":
            rec = {f: v for f, v in rec.items() if f not in _SWING}
        records.append(rec)
    doc = {"format": FORMAT, "version": VERSION, "config": to_dict(cfg), "throws": records}
    Path(path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


class ThrowSet(NamedTuple):
    """A loaded throw-set file: the config and the throws, in file order."""

    config: ThrowConfig
    throws: list[Throw]


def load_throw_set(path: str | Path) -> ThrowSet:
    """Read a throw-set file written by :func:`save_throw_set` (version 1 or 2).

    Raises:
        ThinkfastError: unreadable, not a throw set, unknown version or a bad record; the
            message names the path.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ThinkfastError(f"{path}: cannot read throw set ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ThinkfastError(f"{path}: not a throw-set file (format must be {FORMAT!r})")
    version = doc.get("version")
    if isinstance(version, bool) or version not in READS:
        raise ThinkfastError(
            f"{path}: unknown version {version!r} (this reader knows {', '.join(map(str, READS))})"
        )
    cfg = from_dict(ThrowConfig, doc.get("config"), str(path), "config")
    if version == 1:  # before the thrower model every throw was a still hold
        cfg = dataclasses.replace(cfg, thrower=dataclasses.replace(cfg.thrower, mix=STILL_MIX))
    throws = []
    for i, rec in enumerate(doc.get("throws") or []):
        throws.append(_record(rec, version, f"{path}: throws[{i}]"))
    return ThrowSet(cfg, throws)


def _record(rec: dict, version: int, where: str) -> Throw:
    try:
        if version == 1 and any(f in rec for f in ("kind", *_SWING)):
            raise ValueError("a version 1 record has no kind or swing")
        values = {"id": str(rec["id"]), "kind": str(rec.get("kind", "still"))}
        for f in Throw._fields[1:]:
            if f == "kind" or (f not in rec and f in Throw._field_defaults):
                continue
            if f in _ARRAYS:
                a = np.array(rec[f], dtype=float)
                if a.shape != (_ARRAYS[f],):
                    raise ValueError(f"{f}: expected {_ARRAYS[f]} numbers")
                a.setflags(write=False)
                values[f] = a
            else:
                values[f] = float(rec[f])
        t = Throw(**values)
    except (KeyError, TypeError, ValueError) as exc:
        raise ThinkfastError(f"{where}: bad record ({exc!r})") from None
    if t.kind == "still" and any(f in rec for f in _SWING):
        raise ThinkfastError(f"{where}: a still throw has no swing fields")
    why = check_motion(t)
    if why is not None:
        raise ThinkfastError(f"{where}: {why}")
    return t
