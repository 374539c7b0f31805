"""Joint positions of a few Ruckig trajectories at many clipped times, compiled: the chooser's
joint paths without one ``at_time`` call per sample.

:func:`phases` reads each trajectory's phases once (plain Python lists into one array, no
numpy call per field); :func:`clipped_positions` evaluates them with the arithmetic of
:class:`thinkfast.robot.batch_traj.TrajectoryTable` (Ruckig's own formula, phase choice and
offsets: equal to ``at_time`` bit for bit), one sample at a time (numba without fastmath: the
same IEEE operations in the same order; tests/test_traj_jit.py holds it to ``at_time``).
Compiled on first use and cached on disk (``cache=True``); :func:`warm_up` compiles or loads it
ahead. Pure computation.
Imported only in a process that chose the compiled kernels
(:mod:`thinkfast.robot.kernels`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

_FIELDS = 38  # per joint: phase times (7), jerks (7), p, v, a at the phase starts (8 each)


def phases(trajectories: Sequence) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phases of single-section trajectories of n joints.

    Returns:
        ``(table, brakes, duration)``: per trajectory and joint the phase times, jerks and
        p, v, a, shape (M, n, 38); the brakes (trajectory, joint, duration, end of its first
        phase, p, v, a, j of both phases) as rows (B, 12); the durations [s] (M,).
    """
    vals: list = []
    brakes: list = []
    duration = []
    for m, traj in enumerate(trajectories):
        duration.append(traj.duration)
        for d, prof in enumerate(traj.profiles[0]):
            vals += prof.t
            vals += prof.j
            vals += prof.p
            vals += prof.v
            vals += prof.a
            b = prof.brake
            if b.duration > 0.0:
                brakes.append([m, d, b.duration, b.t[0], *b.p, *b.v, *b.a, *b.j])
    m = len(duration)
    n = len(vals) // (_FIELDS * m) if m else 0
    table = np.array(vals, dtype=float).reshape(m, n, _FIELDS)
    return table, np.array(brakes, dtype=float).reshape(-1, 12), np.array(duration, dtype=float)


@numba.njit(cache=True, nogil=True)
def clipped_positions(table, brakes, duration, times, out):
    """Positions of trajectory m at ``times[m, s]`` clipped to ``[0, duration[m]]`` into
    ``out[m, s]`` (M, S, n) [rad], as ``TrajectoryTable.positions`` (bit for bit)."""
    m_count, n = table.shape[0], table.shape[1]
    brake = np.zeros((m_count, n))
    brake_t = np.zeros((m_count, n))
    bpvaj = np.zeros((m_count, n, 4, 2))
    for r in range(brakes.shape[0]):
        m, d = int(brakes[r, 0]), int(brakes[r, 1])
        brake[m, d], brake_t[m, d] = brakes[r, 2], brakes[r, 3]
        for q in range(4):
            bpvaj[m, d, q, 0], bpvaj[m, d, q, 1] = brakes[r, 4 + 2 * q], brakes[r, 5 + 2 * q]
    t_sum = np.empty(7)
    for m in range(m_count):
        dur = duration[m]
        for d in range(n):
            row = table[m, d]
            acc = row[0]
            t_sum[0] = acc
            for k in range(1, 7):  # partial_sum: sequential, as in Ruckig
                acc += row[k]
                t_sum[k] = acc
            last = t_sum[6]
            bk = brake[m, d]
            for s in range(times.shape[1]):
                tt = min(max(times[m, s], 0.0), dur)
                t = tt - bk if bk > 0.0 else tt
                phase = 0
                for k in range(7):  # upper_bound on the cumulative phase times
                    if t_sum[k] <= t:
                        phase += 1
                local = t - t_sum[max(phase - 1, 0)] if phase > 0 else t
                if t >= last:
                    phase = 7
                    local = t - last
                jerk = row[7 + phase] if phase < 7 else 0.0
                p = _integrate(local, row[14 + phase], row[22 + phase], row[30 + phase], jerk)
                if tt >= dur:  # past the duration: from the end of the last phase
                    p = _integrate(tt - (bk + last), row[21], row[29], row[37], 0.0)
                elif bk > 0.0 and tt < bk:
                    i = 1 if tt >= brake_t[m, d] else 0
                    tb = tt - brake_t[m, d] if i else tt
                    p = _integrate(
                        tb, bpvaj[m, d, 0, i], bpvaj[m, d, 1, i], bpvaj[m, d, 2, i],
                        bpvaj[m, d, 3, i],
                    )  # fmt: skip
                out[m, s, d] = p


@numba.njit(cache=True, nogil=True, inline="always")
def _integrate(t, p0, v0, a0, j):
    """Ruckig's constant-jerk position, operation for operation."""
    return p0 + t * (v0 + t * (a0 / 2 + t * j / 6))


def warm_up() -> None:
    """Compile the kernel (or load it from numba's disk cache) now, with its call types."""
    table = np.zeros((1, 3, _FIELDS))
    out = np.empty((1, 1, 3))
    clipped_positions(table, np.zeros((0, 12)), np.ones(1), np.zeros((1, 1)), out)
