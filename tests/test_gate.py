"""The throw gate (thinkfast.control.gate): when a tracked ball is a throw, on its own.

Fed the scripted 50 Hz detections of tests/test_executor_modes.py (a ball held still, a throw
towards the small tree's goal grid) with the same fixed noise, the way the executor feeds it:
the ``confirm`` gate never confirms a held ball and confirms a throw after its release, the
launch detector confirming it at once; without the launch detector the count does it; the
``first`` gate confirms at the first belief predicting a crossing at zero sigmas and never uses
the launch detector; a ball seen again after ``detection_timeout`` starts the filter afresh.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_executor_modes import CFG, FRAME, HELD, NO_LAUNCH, NOISE, RELEASE, THROW, Ball
from thinkfast.control.gate import ThrowGate
from thinkfast.control.planners.base import CONFIRM, FIRST
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.tree.file import load_tree


@pytest.fixture(scope="module")
def rtree(small_tree_015, robot):
    return runtime_tree(load_tree(small_tree_015), robot, CFG)


def run(gate: ThrowGate, ball: Ball, until: float, seed: int = 3):
    """Feed ``ball`` up to ``until`` [s] as the executor does (armed until confirmed); returns
    (stamp of the confirming detection or None, launched at it, every stamp the launch
    detector restarted the filter)."""
    rng = np.random.default_rng(seed)
    launches = []
    for stamp in np.arange(0.0, until, FRAME):
        p = ball.at(float(stamp))
        if p is None:
            continue
        fused = gate.fuse(float(stamp), p + rng.normal(0.0, NOISE, 3), None, armed=True)
        assert fused.ok and fused.refusal is None
        if fused.launched:
            launches.append(float(stamp))
        if gate.belief.n_meas < 2:
            continue
        if gate.confirms(gate.crossing(), fused.launched, tracking=True):
            return float(stamp), fused.launched, launches
    return None, False, launches


def test_a_held_ball_is_never_a_throw(rtree):
    for kind in (CONFIRM, FIRST):
        gate = ThrowGate(rtree, CFG, kind)
        assert run(gate, HELD, 3.0)[0] is None, kind
        assert gate.belief.n_meas > 100 and not gate.confirmed


def test_the_launch_detector_confirms_a_throw_at_once_after_its_release(rtree):
    gate = ThrowGate(rtree, CFG, CONFIRM)
    t, launched, launches = run(gate, THROW, RELEASE + 0.6)
    assert t is not None and RELEASE < t < RELEASE + 0.3
    assert launched and launches and gate.confirmed


def test_without_the_launch_detector_the_count_confirms(rtree):
    gate = ThrowGate(rtree, NO_LAUNCH, CONFIRM)
    t, launched, launches = run(gate, THROW, RELEASE + 0.6)
    assert t is not None and t > RELEASE and not launched and not launches
    assert gate.confirm == NO_LAUNCH.throw.confirm_updates
    assert gate.settled >= NO_LAUNCH.throw.settle_updates


def test_the_first_gate_confirms_at_the_first_approaching_belief(rtree):
    first = ThrowGate(rtree, CFG, FIRST)
    t_first, launched, launches = run(first, THROW, RELEASE + 0.6)
    assert t_first is not None and t_first > RELEASE and not launched and not launches
    assert first.confirm == 0  # no count: the first gate never turns the wrist on it
    counted = ThrowGate(rtree, NO_LAUNCH, CONFIRM)
    t_count, _, _ = run(counted, THROW, RELEASE + 0.6)
    assert t_first < t_count  # neither settling nor a count


def test_a_ball_seen_again_after_the_timeout_starts_the_filter_afresh(rtree):
    gate = ThrowGate(rtree, CFG, CONFIRM)
    run(gate, HELD, 1.0)
    assert gate.belief.n_meas > 10
    later = 1.0 + CFG.throw.detection_timeout + 0.1
    gate.fuse(later, np.array(HELD.hand), None, armed=True)
    assert gate.belief.n_meas == 1 and gate.confirm == 0
    with pytest.raises(ValueError, match="confirm, first"):
        ThrowGate(rtree, CFG, "second")
