"""``naive``: at every belief, Ruckig from the commanded state to the goal nearest the most likely
crossing point. It leaves home at the confirmation (the launch gate,
:mod:`thinkfast.control.gate`)."""

from __future__ import annotations

from thinkfast.control.planners.base import Act, Belief, EpisodeLog, Planner


class NaivePlanner(Planner):
    """The naive baseline (module doc); its at-rest backup is kept for the status only."""

    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        self.backup(b)
        return self.rush(b)
