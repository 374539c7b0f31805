"""``naive-paper``: the paper's baseline. As ``naive``, from the first belief that predicts a
throw at zero sigmas (mean approach speed), with neither the launch detector, the settling nor
the count (the ``first`` throw gate, :mod:`thinkfast.control.gate`)."""

from __future__ import annotations

from thinkfast.control.planners.base import FIRST
from thinkfast.control.planners.naive import NaivePlanner


class NaivePaperPlanner(NaivePlanner):
    """The paper's naive baseline (module doc)."""

    gate = FIRST
