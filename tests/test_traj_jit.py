"""The compiled joint positions (thinkfast.robot.traj_jit) equal Ruckig's at_time at the clipped
times bit for bit, brakes, phase switches and both ends included."""

from __future__ import annotations

import numpy as np
import pytest
from test_batch_traj import _random_trajectories

from thinkfast.robot.traj_jit import clipped_positions, phases, warm_up

pytestmark = pytest.mark.usefixtures("compiled_kernels")  # the dispatching calls too


def test_clipped_positions_equal_at_time_bit_for_bit_around_every_phase_switch(robot):
    trajs = _random_trajectories(robot, 120, seed=31)
    table, brakes, duration = phases(trajs)
    assert len(brakes) > 20  # brakes were exercised
    knots = []
    for traj in trajs:
        k = [np.cumsum(p.t) for p in traj.profiles[0]]
        k += [[p.brake.duration, p.brake.duration + p.brake.t[0]] for p in traj.profiles[0]]
        knots.append(np.concatenate(k + [[0.0, traj.duration]]))
    width = max(len(k) for k in knots)
    times = np.empty((len(trajs), 60 + 3 * width))
    for m, (traj, k) in enumerate(zip(trajs, knots, strict=True)):
        k = np.resize(k, width)
        times[m] = np.r_[np.linspace(-0.05, 1.1 * traj.duration, 60), k,
                         np.nextafter(k, -1.0), np.nextafter(k, 9.0)]  # fmt: skip
    out = np.empty((len(trajs), times.shape[1], 3))
    clipped_positions(table, brakes, duration, times, out)
    want = np.array(
        [
            [traj.at_time(min(max(t, 0.0), traj.duration))[0] for t in row.tolist()]
            for traj, row in zip(trajs, times, strict=True)
        ]
    )
    assert out.tobytes() == want.tobytes()


def test_warm_up_runs():
    warm_up()
