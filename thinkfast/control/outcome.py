"""What the control core did, returned: one detection's outcome and the core's state for a view.

The daemon records and shows these; it never reaches into the executor. Both are read off the
executor by the core (this module's functions) right after it acts: small named tuples of
references (the belief is the filter's own; copy before keeping it past the next detection).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.control.intake import Accepted
from thinkfast.control.modes import EXECUTING, STAGE_KEYS


class Decision(NamedTuple):
    """The planner's last decision: executor ``mode``, tree ``node`` (0: home), its ``value``
    (probability of a block) and ``goal`` index."""

    mode: str
    node: int
    value: float
    goal: int


class DetectionOutcome(NamedTuple):
    """One detection's outcome (:meth:`~thinkfast.control.core.ControlCore.on_detection`).

    Attributes:
        detection: the detection taken, None when it was dropped.
        dropped: ``(reason, detail)`` when it was dropped (the intake's or the executor's
            refusal, ``planner_error``), else None.
        belief: the ball filter's state after it (its ``n_meas``, ``mean`` (6,), ``cov``).
        crossing: the belief's crossing of the plane (delta method), None below two
            measurements or when the detection was dropped.
        decision: the planner's last :class:`Decision`, None before any.
        mode: the executor's mode after it. started: it began a throw's motion.
        throw: throws begun so far, this one counted. error: a planner failure (it brakes).
        segment: the joint 1-3 segment in progress. wrist: the wrist's joints [rad] (3,).
    """

    detection: Accepted | None
    dropped: tuple[str, str] | None
    belief: object
    crossing: object
    decision: Decision | None
    mode: str
    started: bool
    throw: int
    error: Exception | None
    segment: object
    wrist: np.ndarray


class CoreState(NamedTuple):
    """The executor's part of the status (:meth:`~thinkfast.control.core.ControlCore.state`):
    ``mode``, ``throws`` confirmed, tree ``node``, last ``value`` (None before a decision),
    ``stage`` (``{stage, hedge_end, hedges, throw_end}``), ``cameras`` (their consistency
    check, ``{}`` with one camera), ``away`` (held away from home), ``ended`` (the last episode
    dropped, an :class:`~thinkfast.control.planners.base.EpisodeLog`, or None)."""

    mode: str
    throws: int
    node: int
    value: float | None
    stage: dict
    cameras: dict
    away: bool
    ended: object


class ThrowFigures(NamedTuple):
    """What the simulators judge a run by: ``decisions`` taken (the episode under way's, plus
    one per throw confirmed before it), ``t_start`` [s] of the motion of the throw under way or
    else of the last one (nan: none moved), ``hedges`` begun since the start."""

    decisions: int
    t_start: float
    hedges: int


def figures_of(ex) -> ThrowFigures:
    """The executor's :class:`ThrowFigures`."""
    ep = ex.episode
    if math.isnan(ep.t_start) and ex.last_episode:
        ep = ex.last_episode
    return ThrowFigures(ex.episode.decisions + ex.episodes, ep.t_start, ex.hedges)


def decision_of(ex) -> Decision | None:
    """The executor's last decision, None before any."""
    vg = ex.current_value()
    return None if vg is None else Decision(str(ex.mode), ex.node, vg[0], vg[1])


def outcome_of(ex, det, dropped, was: str, error, with_crossing: bool) -> DetectionOutcome:
    """The outcome of one detection ``det`` (None: ``dropped``), the executor's mode having
    been ``was`` before it; the crossing only ``with_crossing`` (it costs a delta method)."""
    belief = ex.belief
    crossing = None
    if with_crossing and det is not None and belief.n_meas >= 2:
        crossing = ex.tree.crossing(belief.mean, belief.cov, ex.cfg.filter.gravity)
    started = ex.mode == EXECUTING and was != EXECUTING
    return DetectionOutcome(
        det, dropped, belief, crossing, decision_of(ex), str(ex.mode), started,
        ex.episodes + (1 if ex.mode == EXECUTING else 0), error, ex.segment,
        ex.wrist.state[:3].copy(),
    )  # fmt: skip


def state_of(ex) -> CoreState:
    """The executor's part of the status."""
    vg = ex.current_value()
    return CoreState(
        str(ex.mode), ex.episodes, ex.node, None if vg is None else vg[0],
        {k: getattr(ex, k) for k in STAGE_KEYS}, {} if ex.check is None else ex.check.as_dict(),
        ex.away, ex.ended,
    )  # fmt: skip
