"""Batched Ruckig sampling equals ``Trajectory.at_time`` bit for bit, brakes and ends included."""

from __future__ import annotations

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from thinkfast.robot.batch_traj import TrajectoryTable, sample_positions


def _random_trajectories(robot, n: int, seed: int) -> list:
    """Moves to rest from random states; every third starts beyond the limits (a brake)."""
    rng = np.random.default_rng(seed)
    v, a, j = robot.v_max[:3], robot.a_max[:3], robot.j_max[:3]
    otg, inp = Ruckig(3), InputParameter(3)
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = v.tolist(), a.tolist(), j.tolist()
    out = []
    for k in range(n):
        scale = 1.3 if k % 3 == 0 else 0.95
        inp.current_position = rng.uniform(robot.q_lower[:3], robot.q_upper[:3]).tolist()
        inp.current_velocity = (rng.uniform(-1, 1, 3) * v * scale).tolist()
        inp.current_acceleration = (rng.uniform(-1, 1, 3) * a * scale).tolist()
        inp.target_position = rng.uniform(robot.q_lower[:3], robot.q_upper[:3]).tolist()
        traj = Trajectory(3)
        if otg.calculate(inp, traj) in (Result.Working, Result.Finished):
            out.append(traj)
    return out


def test_positions_equal_at_time_bit_for_bit_at_and_around_every_phase_switch(robot):
    trajs = _random_trajectories(robot, 300, seed=21)
    table = TrajectoryTable(trajs)
    assert np.count_nonzero(table.brake) > 50  # brakes were exercised
    owner, times = [], []
    for m, traj in enumerate(trajs):
        knots = np.concatenate(
            [np.cumsum(p.t) for p in traj.profiles[0]]
            + [[0.0, traj.duration], table.brake[m], table.brake[m] + table.brake_t[m]]
        )
        t = np.r_[np.linspace(-0.01, 1.1 * traj.duration, 60), knots,
                  np.nextafter(knots, -1.0), np.nextafter(knots, 9.0)]  # fmt: skip
        owner.append(np.full(len(t), m))
        times.append(t)
    owner, times = np.concatenate(owner), np.concatenate(times)
    got = table.positions(owner, times)
    want = np.array([trajs[m].at_time(float(t))[0] for m, t in zip(owner, times, strict=True)])
    assert np.array_equal(got, want)


def test_sample_positions_shapes_and_values(robot):
    trajs = _random_trajectories(robot, 5, seed=22)
    times = np.linspace(0.0, 0.5, 7)
    got = sample_positions(trajs, times)
    assert got.shape == (len(trajs), 7, 3)
    assert np.array_equal(got[2, 4], trajs[2].at_time(float(times[4]))[0])
    assert sample_positions([], times).shape[:2] == (0, 7)
