"""A flight record in the Rerun viewer: the live view's entities, offline (docs/LIVE_VIEW.md).

``thinkfast-sim replay RECORD --rerun ...`` and ``thinkfast-sim record view``. What the record
holds is drawn with the live view's :class:`~thinkfast.view.rerun_painter.Painter` on the same
``time`` timeline (the record's Unix times): raw and accepted detections, beliefs and their
plane crossings, decisions (mode, node, value, best goal; a record keeps no motion, so no
shield path), the arm at the commanded and measured joints (EGM rows, at most ``joint_rate``
per second) and the daemon's events. The goal grid comes from ``tree`` when given.
"""

from __future__ import annotations

from pathlib import Path

from thinkfast.record.format import Record
from thinkfast.record.tables import run_config
from thinkfast.view.live import ViewSink, open_stream
from thinkfast.view.replay import log_record, plane_and_goals
from thinkfast.view.rerun_painter import Painter


def drawing_inputs(record: Record, tree: Path | None):
    """What a view draws ``record`` with: (its run configuration, the robot it names, the
    plane's x [m] or None, the goal grid (G, 2) [m] or None; see
    :func:`~thinkfast.view.replay.plane_and_goals`).

    Raises:
        ConfigError: the record's run configuration does not validate.
        TreeFileError: ``tree`` cannot be read.
    """
    from thinkfast.view.replay import record_robot

    cfg = run_config(record)
    return (cfg, record_robot(record, cfg, tree), *plane_and_goals(record, tree))


def record_to_rerun(
    record: Record, sink: ViewSink, tree: Path | None = None, joint_rate: float = 50.0
) -> dict[str, int]:
    """Log ``record`` to ``sink``; returns the rows logged per kind.

    Raises:
        ConfigError: rerun-sdk missing, the sink cannot be opened, or the record's run
            configuration does not validate.
        TreeFileError: ``tree`` cannot be read.
    """
    cfg, robot, px, goal_yz = drawing_inputs(record, tree)
    rec = open_stream(sink, f"record {record.path.name}")
    p = Painter(rec, robot, px if px is not None else 0.0, goal_yz)
    counts = log_record(p, record, cfg, joint_rate, crossings=px is not None)
    p.close()
    return counts
