"""Record the tree planner's decision calls for ``bench/decision_replay.py`` (its ``record``
and ``compare``): every ``Chooser.choose`` and every run of the hedge stage of simulated throws
flown as ``bench/decision.py --planners tree`` flies them, with the Ruckig trajectories kept as
their solver inputs (solved again on replay: Ruckig is deterministic).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CHOOSE, HEDGE = "choose", "hedge"


def record(tree_path: Path, n_throws: int, seed: int) -> dict:
    """Every decision call of ``n_throws`` lockstep throws (``bench/decision.py``'s loop)."""
    import thinkfast  # first: the package of this checkout or PYTHONPATH's (decision.py
    # puts this checkout first on sys.path, which then no longer decides)

    sys.path.insert(0, str(ROOT / "bench"))
    import decision  # bench/decision.py: the same throws, detections and executor loop

    print(f"recording with {Path(thinkfast.__file__).parent}", file=sys.stderr)

    from thinkfast.control.hedge_stage import HedgeStage
    from thinkfast.decide.choice import Chooser
    from thinkfast.robot.steering import Steering

    specs: dict[int, tuple] = {}  # id(trajectory) -> (trajectory, solver inputs)
    calls: list[tuple] = []
    to_rest, choose, on_belief = Steering.to_rest, Chooser.choose, HedgeStage.on_belief

    def spec_of(traj):
        return None if traj is None else specs.get(id(traj), (None, False))[1]

    def rec_to_rest(self, state, target):
        traj = to_rest(self, state, target)
        if traj is not None:
            limits = tuple(x.tolist() for x in (self.v_max, self.a_max, self.j_max))
            inputs = [float(x) for x in state], [float(x) for x in target]
            specs[id(traj)] = (traj, (limits, *inputs))
        return traj

    def rec_choose(self, mean, cov, approach, t_belief, t_plan, lag, state, current, *rest):
        best, options = choose(
            self, mean, cov, approach, t_belief, t_plan, lag, state, current, *rest
        )
        spec = spec_of(current.traj)  # False: not a Ruckig move of a Steering (not replayed)
        if spec is not False and not any(r is not None for r in rest):  # branches off (default)
            seg = (float(current.t0), np.array(current.end, dtype=float), spec)
            args = (
                np.array(mean, dtype=float),
                np.array(cov, dtype=float),
                None if approach is None else np.array(approach, dtype=float),
                float(t_belief),
                float(t_plan),
                float(lag),
                np.array(state, dtype=float),
            )
            calls.append((CHOOSE, args, seg, [o.value for o in options]))
        return best, options

    def rec_on_belief(self, t_now, stamp, points, ep):
        if not self.off:
            pts = [(float(p[0]), np.array(p[1]), np.array(p[2])) for p in points]
            state = np.array(self.timeline.state(t_now), dtype=float)
            calls.append((HEDGE, (float(t_now), float(stamp), pts, state), None, None))
        return on_belief(self, t_now, stamp, points, ep)

    each = getattr(Steering, "to_rest_each", None)

    def rec_to_rest_each(self, state, targets):
        return [rec_to_rest(self, state, target) for target in targets]

    Steering.to_rest, Chooser.choose, HedgeStage.on_belief = rec_to_rest, rec_choose, rec_on_belief
    if each is not None:
        Steering.to_rest_each = rec_to_rest_each
    try:
        decision.time_planners(tree_path, ["tree"], n_throws, seed)
    finally:
        Steering.to_rest, Chooser.choose, HedgeStage.on_belief = to_rest, choose, on_belief
        if each is not None:
            Steering.to_rest_each = each
    return {"tree": str(tree_path), "throws": n_throws, "seed": seed, "calls": calls}
