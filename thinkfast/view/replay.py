"""A flight record drawn by a painter: the live views' calls, offline.

:func:`log_record` calls a painter (the Rerun view's
:class:`~thinkfast.view.rerun_painter.Painter`, or
:class:`~thinkfast.view.channels.ChannelPainter` for Foxglove's scene in the MCAP export)
with what the record holds, at the record's Unix times: raw and accepted detections, beliefs and
their plane crossings, decisions (mode, node, value, best goal; a record keeps no motion, so no
shield path), the arm at the commanded and measured joints (EGM rows, at most ``joint_rate`` per
second) and the daemon's events. :func:`timed_calls` keeps the same calls in time order, for a
replay at the record's pace (``thinkfast-sim replay --foxglove``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from thinkfast.record.format import MODES, Record
from thinkfast.record.tables import columns, event_times, plane_x, raw_positions


def plane_and_goals(record: Record, tree: Path | None) -> tuple[float | None, np.ndarray | None]:
    """The blocking plane's x [m] and the goal grid (G, 2) [m] to draw ``record`` with: from
    ``tree`` when given, else the plane from the record's crossings (None when none) and no
    grid.

    Raises:
        TreeFileError: ``tree`` cannot be read.
    """
    if tree is None:
        return plane_x(record), None
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.provenance import Provenance

    t = load_tree(tree)
    return Provenance.of(t.meta).plane_x, t.goal_yz


def record_robot(record: Record, cfg, tree: Path | None = None):
    """The robot ``record`` was flown with, in the frame of its estimates, to draw it with.

    With ``tree``: the tree's robot (:func:`~thinkfast.tree.robot_match.robot_for_tree`),
    refused when the record was made with another. Without: robot.toml at the path the record
    names (``robot_toml``), else the run config's ``robot``, else the default, refused unless
    its hash is the one recorded; placed in the record's plane
    (:func:`~thinkfast.record.tables.record_plane`).

    Raises:
        RobotModelError: the robot found is not the record's (names both), or cannot be loaded.
        TreeFileError: ``tree`` cannot be read.
    """
    from thinkfast.errors import RobotModelError
    from thinkfast.record.tables import record_plane
    from thinkfast.robot.model import load_robot

    want = record.attrs.get("robot_toml_sha256")
    name = record.attrs.get("robot_name", "?")
    if tree is not None:
        from thinkfast.tree.file import load_tree
        from thinkfast.tree.robot_match import robot_for_tree

        robot = robot_for_tree(load_tree(tree).meta, str(tree), cfg.robot or None)
    else:
        named = record.attrs.get("robot_toml")
        path = Path(named) if named and Path(named).is_file() else None
        robot = load_robot(path or (Path(cfg.robot) if cfg.robot else None))
        plane = record_plane(record)
        robot = robot if plane is None else robot.placed(plane)
    if want and want != robot.toml_sha256:
        raise RobotModelError(
            f"{record.path}: flown with {name} (robot.toml {str(want)[:12]}), but the robot found "
            f"is {robot.name} (robot.toml {robot.toml_sha256[:12]}) from {robot.toml_path}: pass "
            "--tree with the record's tree"
        )
    return robot


def decimate(t: np.ndarray, rate: float) -> np.ndarray:
    """Indices of the rows of times ``t`` [s] (non-decreasing) at most ``rate`` per second."""
    keep, next_t = [], -np.inf
    for i, ti in enumerate(t):
        if ti >= next_t:
            keep.append(i)
            next_t = ti + 1.0 / rate
    return np.array(keep, dtype=int)


def log_record(p, record: Record, cfg, joint_rate: float, crossings=True) -> dict:
    """Draw every stream of ``record`` with ``p`` (see the module doc); rows logged per kind."""
    raw = raw_positions(record, cfg)
    for t, pos in zip(raw.t, raw.position, strict=True):
        p.raw(t, pos)
    det = columns(record, "detections")
    for t, pos in zip(det["t_recv"], np.c_[det["x"], det["y"], det["z"]], strict=True):
        p.accepted(t, pos)
    b = columns(record, "beliefs")
    n_cross = 0
    for i, t in enumerate(b["t"]):
        p.belief(t, b["mean"][i], b["cov"][i].reshape(6, 6))
        if crossings and b["crossing_ok"][i] > 0.5:
            p.crossing(t, b["o_mean"][i], b["o_cov"][i].reshape(3, 3))
            n_cross += 1
    d = columns(record, "decisions")
    for t, mode, node, value, goal in zip(
        d["t"], d["mode"], d["node"], d["value"], d["best_goal"], strict=True
    ):
        name = MODES[int(mode)] if 0 <= mode < len(MODES) else "?"
        text = f"{name}: node {int(node)}, best goal {int(goal)}, value {value:.3f}"
        p.decision(t, text, float(value), int(goal), None)
    e = columns(record, "egm")
    keep = decimate(e["t"], joint_rate)
    for i in keep:
        t = e["t"][i]
        p.joints(t, e["q_cmd"][i], e["qd_cmd"][i], e["q_fb"][i])
        p.arm(t, "commanded", e["q_cmd"][i])
        p.arm(t, "measured", e["q_fb"][i])
    for t, ev in zip(event_times(record), record.events, strict=True):
        p.event(t, ev.kind, json.dumps(ev.detail))
    return {
        "raw": len(raw.t),
        "accepted": len(det["t_recv"]),
        "beliefs": len(b["t"]),
        "crossings": n_cross,
        "decisions": len(d["t"]),
        "joints": len(keep),
        "events": len(record.events),
    }


PAINTER_CALLS = ("raw", "accepted", "belief", "crossing", "decision", "joints", "arm", "event")


class CallList:
    """A painter that keeps the calls made to it: ``calls`` holds (time [s], method name,
    the other arguments) in the order they were made."""

    def __init__(self):
        self.calls: list[tuple[float, str, tuple]] = []

    def __getattr__(self, name: str):
        if name not in PAINTER_CALLS:
            raise AttributeError(name)
        return lambda t, *args: self.calls.append((float(t), name, args))


def timed_calls(record: Record, cfg, joint_rate: float, crossings=True) -> list:
    """The painter calls :func:`log_record` makes for ``record``, as (time [s], method name,
    other arguments) in time order. The sort is stable: calls at one time keep
    :func:`log_record`'s order, so a painter fed these draws what it draws from
    :func:`log_record` sorted by time (the MCAP's scene, ``channels.scene_messages``)."""
    painter = CallList()
    log_record(painter, record, cfg, joint_rate, crossings)
    return sorted(painter.calls, key=lambda call: call[0])
