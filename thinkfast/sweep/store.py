"""A sweep's results directory: trees, one file per finished chunk of throws and one per
finished point, each written atomically, so a rerun finds what is done (docs/SWEEPS.md)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from thinkfast.sim.lockstep import Outcome
from thinkfast.sweep.spec import Point, Sweep

# --- outcomes on disk -----------------------------------------------------------------------


def outcome_rows(outcomes: list[Outcome]) -> list[list[Any]]:
    """Outcomes as JSON-able rows (field order of :class:`Outcome`)."""
    return [list(o) for o in outcomes]


def outcomes_from_rows(rows: list[list[Any]]) -> list[Outcome]:
    """Inverse of :func:`outcome_rows` (floats survive JSON exactly, NaN included)."""
    return [Outcome(*r) for r in rows]


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename (never half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class SweepStore:
    """The results directory: ``trees/KEY.h5`` (and the ``.toml`` it was compiled from),
    ``chunks/POINT/START-STOP.json``, ``points/POINT.json``, and the tables and plot."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def tree_path(self, key: str) -> Path:
        return self.root / "trees" / f"{key[:16]}.h5"

    def save_tree(self, key: str, data: bytes, config_text: str | None = None) -> None:
        if config_text is not None:
            write_atomic(self.tree_path(key).with_suffix(".toml"), config_text.encode("utf-8"))
        write_atomic(self.tree_path(key), data)

    def chunk_path(self, point: str, start: int, stop: int) -> Path:
        return self.root / "chunks" / point[:16] / f"{start:06d}-{stop:06d}.json"

    def save_chunk(self, point: str, start: int, stop: int, outcomes, seconds: float) -> None:
        doc = {"start": start, "stop": stop, "seconds": round(seconds, 3),
               "outcomes": outcome_rows(outcomes)}  # fmt: skip
        write_atomic(self.chunk_path(point, start, stop), json.dumps(doc).encode("utf-8"))

    def load_chunk(self, point: str, start: int, stop: int) -> tuple[list[Outcome], float] | None:
        """The chunk's outcomes and seconds, or None when it is not on disk (or unreadable)."""
        try:
            doc = json.loads(self.chunk_path(point, start, stop).read_text(encoding="utf-8"))
            return outcomes_from_rows(doc["outcomes"]), float(doc["seconds"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def point_path(self, point: str) -> Path:
        return self.root / "points" / f"{point[:16]}.json"

    def save_point(self, doc: dict) -> None:
        write_atomic(self.point_path(doc["point_key"]), json.dumps(doc).encode("utf-8"))

    def load_point(self, point: str) -> dict | None:
        try:
            return json.loads(self.point_path(point).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None


def point_doc(sweep: Sweep, point: Point, outcomes: list[Outcome], seconds: float) -> dict:
    """A finished point: its values, keys and the bench summary of its outcomes (the same dict
    ``thinkfast-sim bench --json`` prints, ``seconds`` being simulation time summed over the
    chunks)."""
    from thinkfast.sim.bench import summarize

    summary = summarize(outcomes, list(sweep.settings.planners), sweep.reference)
    summary["seconds"] = round(seconds, 1)
    summary["seed"] = sweep.settings.seed
    return {
        "index": point.index,
        "params": point.params,
        "tree_key": point.tree_key,
        "point_key": point.point_key,
        "summary": summary,
    }
