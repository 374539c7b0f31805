"""The segment timeline (thinkfast.control.timeline): the commanded joint 1-3 motion.

Real Ruckig on the default robot: the way home stays within the return limits and ends home at
rest, also from faster than those limits; when nothing plans it holds; a move Ruckig cannot
plan leaves the segment in progress as it was; a resync plans the same intent again from the
given state and comes to rest when nothing plans; a move clears a queued edge; the way home from
an arm speeding up near its velocity limit stays within the full limits.
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.config import ExecutionConfig
from thinkfast.control.planners.base import EpisodeLog, Follow, follow
from thinkfast.control.segments import HOLD, RETURN, STEER, Segment
from thinkfast.control.timeline import Timeline

CFG = ExecutionConfig()


def _moving(tl: Timeline, robot, speed: float, t: float = 0.0) -> None:
    """Put the timeline on a hold at the middle of joints 1-3 moving at ``speed`` of the full
    velocity limits (a state a real plan passes through)."""
    mid = (np.asarray(robot.q_lower[:3]) + np.asarray(robot.q_upper[:3])) / 2
    state = np.r_[mid, speed * np.asarray(robot.v_max[:3]), np.zeros(3)]
    tl.segment = Segment(HOLD, t, None, state, 0.0)


def test_the_way_home_ends_home_at_rest_within_the_return_limits(robot):
    tl = Timeline(robot, CFG)
    _moving(tl, robot, 0.0)
    tl.start_return(1.0)
    seg = tl.segment
    assert seg.kind == RETURN and not tl.at_home(1.0)
    assert tl.at_home(seg.t_end)
    scale = CFG.return_speed_scale
    for s in np.linspace(1.0, seg.t_end, 50):
        assert np.all(np.abs(tl.state(s)[3:6]) <= scale * robot.v_max[:3] + 1e-9)


def test_from_a_fast_state_it_still_ends_home_and_a_hold_when_nothing_plans(robot):
    tl = Timeline(robot, CFG)
    _moving(tl, robot, 0.95)  # faster than the return limits allow
    tl.start_return(0.0)
    assert tl.segment.kind == RETURN and tl.at_home(tl.segment.t_end)
    wild = np.r_[robot.home[:3], 1e4, 1e4, 1e4, np.zeros(3)]  # Ruckig plans nothing from here
    tl.segment = Segment(HOLD, 0.0, None, wild, 0.0)
    tl.start_return(1.0)
    assert tl.segment.kind == HOLD and np.array_equal(tl.state(2.0)[:3], wild[:3])


def test_a_move_that_cannot_be_planned_keeps_the_segment_in_progress(robot):
    """A move Ruckig cannot plan is None and changes nothing; one it plans changes nothing
    either until it is followed, and following it drops the queued edge."""
    tl = Timeline(robot, CFG)
    tl.pending = (3, 0.5)
    before = tl.segment
    assert tl.steer_segment(np.full(3, np.nan), 2, 0.0) is None
    follow(tl, EpisodeLog(), None)
    assert tl.segment is before and tl.pending == (3, 0.5)
    seg = tl.steer_segment(np.asarray(robot.home[:3]) + 0.2, 2, 0.0)
    assert tl.segment is before and tl.pending == (3, 0.5)
    follow(tl, EpisodeLog(), Follow(seg, None))
    assert tl.segment.kind == STEER and tl.segment.ref == 2 and tl.pending is None


def test_a_resync_plans_the_same_intent_again_or_comes_to_rest(robot):
    tl = Timeline(robot, CFG)
    target = np.asarray(robot.home[:3]) + 0.3
    state = np.r_[robot.home[:3], 0.2, 0.0, 0.0, np.zeros(3)]
    tl.replan(state, STEER, target, 4, 2.0)
    seg = tl.segment
    assert seg.kind == STEER and seg.ref == 4 and np.allclose(seg.end[:3], target)
    assert np.allclose(tl.state(2.0), state)  # continuous: it starts from the given state
    rest = np.r_[target, np.zeros(6)]
    tl.replan(rest, HOLD, target, -1, 3.0)
    assert tl.segment.kind == HOLD and tl.segment.traj is None
    wild = np.r_[robot.home[:3], 1e4, 1e4, 1e4, np.zeros(3)]  # Ruckig plans nothing from here
    tl.replan(wild, STEER, target, 4, 4.0)
    assert tl.segment.kind == HOLD


def test_the_way_home_from_an_arm_speeding_up_stays_within_the_full_limits(robot):
    """At ``--speed-scale`` 0.2, on a long move of the full limits (joint 1 by 1.2 rad) with
    joint 1 still speeding up close to its velocity limit: with the return limits' jerk the
    speed would rise past the full velocity limit before it falls; the way home brakes with the
    full jerk instead (the return speed stays)."""
    from thinkfast.control.segments import move
    from thinkfast.daemon.cli import scale_limits
    from thinkfast.robot.steering import peaks, state_at

    tl = Timeline(scale_limits(robot, 0.2), CFG)
    tl.segment = move(tl.steer, STEER, tl.state(0.0), tl.home + np.array([1.2, 0.0, 0.0]), 0.0)
    traj, v_max = tl.segment.traj, tl.steer.v_max
    t = next(
        t
        for t in np.arange(0.0, traj.duration, 0.004)
        if (s := state_at(traj, t))[3] > 0.9 * v_max[0] and s[6] > 0.0
    )
    state = tl.state(t)
    slow_jerk = move(tl.steer_home, RETURN, state, tl.home, t)
    assert np.any(peaks(slow_jerk.traj)[0] > v_max * 1.001)  # what it used to do
    tl.start_return(t)
    assert tl.segment.kind == RETURN and tl.at_home(tl.segment.t_end)
    v_peak, a_peak = peaks(tl.segment.traj)
    assert np.all(v_peak <= v_max * (1 + 1e-9)) and np.all(a_peak <= tl.steer.a_max * (1 + 1e-9))
    np.testing.assert_array_equal(tl.state(t), state)  # continuous: p, v and a
