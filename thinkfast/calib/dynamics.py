"""Controller lag, achieved acceleration and jerk from commanded vs measured joints.

Input: the ``egm`` table of a flight record (docs/RECORD_FORMAT.md): per exchange the
controller's sequence number, the measured joints ``q_fb`` and the setpoint sent ``q_cmd``,
``qd_cmd`` (rows while braking are left out). Motion is timed by the **controller's clock**:
``seqno x cycle`` (the controller sends one ``EgmRobot`` per cycle and numbers them), never by
the daemon's receive times, which a loaded host delays by anything from 0 to tens of ms. Both
are resampled on a uniform grid at the cycle (4 ms for EGM).

* **Lag** per joint and motion segment: the shift ``tau`` minimising
  ``sum (q_fb(t) - q_cmd(t - tau) - offset)^2``, the commanded path interpolated with its
  velocity (cubic Hermite), ``tau`` in [0, ``max_lag``] to 0.1 ms (bounded scalar search after a
  0.5 ms grid); a segment is a stretch of commanded motion, and a joint counts in it when it
  moved more than ``min_travel``. The joint's lag is the median over its segments, the
  controller lag the median over all (segment, joint) pairs: moves the arm could not follow
  (limits reached) shift only a minority.
* **Acceleration and jerk** per joint: second and third derivatives of Savitzky-Golay fits
  (cubic over ``accel_window`` and ``jerk_window``), then the largest value *held* for at least
  ``hold``: the maximum of a running minimum of the magnitude over ``hold``, so single-sample
  noise never counts. The same for the commanded path tells whether the arm was *limited*
  (achieved below ``limited_ratio`` times commanded): only then is its limit measured; a joint
  that followed everything it was given has a limit of at least what it achieved.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.ndimage import minimum_filter1d
from scipy.optimize import minimize_scalar
from scipy.signal import savgol_filter

from thinkfast.errors import RecordFileError
from thinkfast.record.format import read_record


class DynamicsOptions(NamedTuple):
    """Estimator settings (defaults suit EGM at 4 ms and encoder-grade feedback noise)."""

    max_lag: float = 0.2  # s, longest lag searched
    min_travel: float = 0.05  # rad, a joint counts in a segment when it moved this much
    motion_speed: float = 0.02  # rad/s, commanded speed that marks motion
    accel_window: float = 0.052  # s, Savitzky-Golay window for the acceleration (13 samples)
    jerk_window: float = 0.084  # s, Savitzky-Golay window for the jerk (21 samples)
    hold: float = 0.02  # s, an acceleration or jerk counts when held this long
    limited_ratio: float = 0.9  # achieved below this times commanded: the arm was limited
    min_seconds: float = 1.0  # shortest record accepted
    min_motion: float = 0.1  # s, shortest stretch of commanded motion that counts as a segment
    break_tolerance: float = 2e-5  # rad, a commanded step this far off its velocities ...
    break_slip: float = 0.001  # s, ... and off by more than this clock slip is a timing break
    approach: float = 0.8  # a limit is measured only where the command reached this x it


class JointDynamics(NamedTuple):
    """Per joint: ``lag`` [s] (NaN: never moved enough), ``segments`` used for it, achieved and
    commanded peak acceleration [rad/s^2] and jerk [rad/s^3], and whether each was limited."""

    lag: float
    segments: int
    accel: float
    accel_cmd: float
    accel_limited: bool
    jerk: float
    jerk_cmd: float
    jerk_limited: bool


class DynamicsEstimate(NamedTuple):
    """``lag`` [s] (median over segments and joints), ``joints`` (6), ``dt`` [s] grid,
    ``seconds`` of record used, ``segments`` of motion found, timing ``breaks`` found
    (:func:`timing_breaks`) and the ``excluded`` seconds around them."""

    lag: float
    joints: list[JointDynamics]
    dt: float
    seconds: float
    segments: int
    breaks: int = 0
    excluded: float = 0.0


class EgmRows(NamedTuple):
    """The ``egm`` rows of a record on the controller's clock.

    Attributes:
        t: controller time [s] (N,), ``seqno x cycle`` from each session's first row, increasing.
        t_recv: the daemon's receive times [s] (N,) (kept for reference only).
        q_fb: measured joints [rad] (N, 6).
        q_cmd, qd_cmd: setpoints sent [rad], [rad/s] (N, 6).
        cycle: the controller's cycle [s].
        sessions: EGM sessions found (the sequence number restarted between them).
    """

    t: np.ndarray
    t_recv: np.ndarray
    q_fb: np.ndarray
    q_cmd: np.ndarray
    qd_cmd: np.ndarray
    cycle: float
    sessions: int


def egm_arrays(path: str, cycle: float | None = None) -> EgmRows:
    """The ``egm`` table of a flight record, without the rows sent while braking, timed by the
    controller's sequence numbers (:func:`controller_time`).

    Args:
        path: flight record (HDF5).
        cycle: the controller's cycle [s] (None: the record's run config ``safety.dt``, else 4 ms).

    Raises:
        RecordFileError: not a readable flight record, no EGM rows, or sequence numbers that do
            not match the cycle (names the path).
    """
    rec = read_record(path)
    egm = rec.tables["egm"]
    if egm.ndim != 2 or egm.shape[0] == 0:
        raise RecordFileError(f"{path}: no egm rows (record a run with thinkfast-run --record)")
    if cycle is None:
        cycle = _record_cycle(rec.attrs.get("run_config"))
    egm = egm[egm[:, 20] == 0.0]
    if len(egm) == 0:
        raise RecordFileError(f"{path}: every egm row was sent while braking")
    t, keep, sessions = controller_time(egm[:, 1], egm[:, 0], cycle, str(path))
    egm = egm[keep]
    return EgmRows(t, egm[:, 0], egm[:, 2:8], egm[:, 8:14], egm[:, 14:20], cycle, sessions)


def _record_cycle(run_config) -> float:
    """``safety.dt`` of a record's run config (JSON text), else the EGM cycle of 4 ms."""
    import json

    try:
        return float(json.loads(run_config)["safety"]["dt"])
    except (TypeError, ValueError, KeyError):
        return 0.004


def controller_time(
    seqno: np.ndarray, t_recv: np.ndarray, cycle: float, source: str = "record"
) -> tuple[np.ndarray, np.ndarray, int]:
    """Controller time of each row from its sequence number (pure).

    A session is a run of rows whose ``seqno`` increases (the controller restarts it with a new
    EGM session); within one, time is ``(seqno - seqno_0) x cycle`` after the session's first
    receive time (relative to the record's first), so sessions stay apart. Rows repeating a
    sequence number (or going back in time across sessions) are left out.

    Args:
        seqno: the controller's sequence numbers (N,).
        t_recv: the daemon's receive times [s] (N,).
        cycle: the controller's cycle [s].
        source: name for messages.

    Returns:
        ``t`` [s] (M,) increasing, ``keep`` (N,) bool mask of the rows ``t`` times, sessions.

    Raises:
        RecordFileError: a session whose sequence numbers span a time that the receive times
            contradict by more than 25 % (a wrong cycle, or no controller numbering).
    """
    seqno, t_recv = np.asarray(seqno, dtype=float), np.asarray(t_recv, dtype=float)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(seqno) <= 0) + 1, [len(seqno)]])
    t = np.empty(len(seqno))
    for a, b in zip(starts[:-1], starts[1:], strict=True):
        span_c, span_r = (seqno[b - 1] - seqno[a]) * cycle, t_recv[b - 1] - t_recv[a]
        if span_r > 1.0 and not 0.8 < span_c / span_r < 1.25:
            raise RecordFileError(
                f"{source}: sequence numbers x {1e3 * cycle:g} ms span {span_c:.2f} s where the "
                f"packets arrived over {span_r:.2f} s: not the controller's cycle"
            )
        t[a:b] = (t_recv[a] - t_recv[0]) + (seqno[a:b] - seqno[a]) * cycle
    keep = np.ones(len(t), dtype=bool)
    last = -np.inf
    for i, x in enumerate(t):  # repeated numbers; a session starting before the last ended
        keep[i] = x > last
        last = max(last, x)
    return t[keep], keep, len(starts) - 1


def estimate_dynamics(
    t: np.ndarray,
    q_fb: np.ndarray,
    q_cmd: np.ndarray,
    qd_cmd: np.ndarray,
    opts: DynamicsOptions = DynamicsOptions(),
    source: str = "record",
    cycle: float | None = None,
) -> DynamicsEstimate:
    """Lag and achieved acceleration and jerk from commanded vs measured joints (see module).

    Args:
        t: exchange times [s] (N,), increasing.
        q_fb: measured joints [rad] (N, 6).
        q_cmd, qd_cmd: setpoints sent [rad], [rad/s] (N, 6).
        opts: estimator settings.
        source: name for messages.
        cycle: grid step [s] (None: the median step of ``t``).

    Raises:
        RecordFileError: too short, times not increasing, or no motion to measure.
    """
    t = np.asarray(t, dtype=float)
    if len(t) < 3 or t[-1] - t[0] < opts.min_seconds:
        raise RecordFileError(
            f"{source}: {len(t)} egm rows over {t[-1] - t[0] if len(t) else 0.0:.2f} s; "
            f"at least {opts.min_seconds:g} s needed"
        )
    if not (np.diff(t) > 0).all():
        raise RecordFileError(f"{source}: egm times are not increasing")
    dt = float(np.median(np.diff(t))) if cycle is None else cycle
    grid = np.arange(t[0], t[-1], dt)
    cmd = CubicHermiteSpline(t, q_cmd, qd_cmd, axis=0)
    fb = np.column_stack([np.interp(grid, t, q_fb[:, j]) for j in range(6)])
    qc = cmd(grid)
    brk = np.searchsorted(grid, t[timing_breaks(t, q_cmd, qd_cmd, opts)])
    segs = split_at(motion_segments(cmd(grid, 1), dt, opts), brk, opts.min_motion / dt)
    ignore = np.zeros(len(grid), dtype=bool)
    reach = int(np.ceil((opts.jerk_window / 2 + opts.hold) / dt))
    for i in brk:
        ignore[max(i - reach, 0) : i + reach + 1] = True
    if not segs:
        raise RecordFileError(
            f"{source}: no commanded motion (speed above {opts.motion_speed} rad/s) to measure"
        )
    lags: list[list[float]] = [[] for _ in range(6)]
    # one joint's path alone for the shift search (the same values as that column of cmd's)
    joint_cmd = [CubicHermiteSpline(t, q_cmd[:, j], qd_cmd[:, j]) for j in range(6)]
    for a, b in segs:
        for j in range(6):
            if np.ptp(qc[a:b, j]) < opts.min_travel:
                continue
            lags[j].append(best_shift(grid[a:b], fb[a:b, j], joint_cmd[j], opts.max_lag))
    joints = []
    for j in range(6):
        acc, acc_c = (held_peak(x[:, j], dt, 2, opts, ignore) for x in (fb, qc))
        jrk, jrk_c = (held_peak(x[:, j], dt, 3, opts, ignore) for x in (fb, qc))
        joints.append(
            JointDynamics(
                lag=float(np.median(lags[j])) if lags[j] else float("nan"),
                segments=len(lags[j]),
                accel=acc,
                accel_cmd=acc_c,
                accel_limited=bool(acc < opts.limited_ratio * acc_c),
                jerk=jrk,
                jerk_cmd=jrk_c,
                jerk_limited=bool(jrk < opts.limited_ratio * jrk_c),
            )
        )
    every = [x for row in lags for x in row]
    if not every:
        raise RecordFileError(
            f"{source}: no joint moved more than {opts.min_travel} rad in a motion segment"
        )
    return DynamicsEstimate(
        float(np.median(every)), joints, dt, grid[-1] - grid[0], len(segs), len(brk),
        float(ignore.sum() * dt),
    )  # fmt: skip


def timing_breaks(
    t: np.ndarray, q_cmd: np.ndarray, qd_cmd: np.ndarray, opts: DynamicsOptions
) -> np.ndarray:
    """Rows (N,) bool whose commanded step from the row before disagrees with the commanded
    velocities: ``|dq - (qd + qd_prev) dt / 2|`` above ``break_tolerance`` and above what a
    clock slip of ``break_slip`` would leave. A smooth plan sampled on the controller's clock
    agrees to within ``jerk dt^3 / 12`` (below 1e-6 rad at 4 ms); a disagreement means the
    plan's time jumped against the controller's (the daemon resynchronised its clock after a
    silence, a stalled simulated controller) or the supervisor changed the setpoint: the
    acceleration there is the jump's, not a motion's."""
    dt = np.diff(t)[:, None]
    step = np.diff(q_cmd, axis=0)
    err = np.abs(step - 0.5 * (qd_cmd[1:] + qd_cmd[:-1]) * dt)
    speed = 0.5 * np.abs(qd_cmd[1:] + qd_cmd[:-1])
    bad = ((err > opts.break_tolerance) & (err > speed * opts.break_slip)).any(axis=1)
    return np.concatenate([[False], bad])


def split_at(segs: list[tuple[int, int]], cuts: np.ndarray, shortest: float) -> list:
    """``segs`` (index ranges ``[a, b)``) cut at the indices ``cuts``; pieces shorter than
    ``shortest`` samples are left out."""
    out = []
    for a, b in segs:
        edges = [a, *sorted(int(c) for c in cuts if a < c < b), b]
        out += [(x, y) for x, y in zip(edges[:-1], edges[1:], strict=True) if y - x >= shortest]
    return out


def motion_segments(qd: np.ndarray, dt: float, opts: DynamicsOptions) -> list[tuple[int, int]]:
    """Index ranges ``[a, b)`` of commanded motion (any joint faster than ``motion_speed``) of
    at least ``min_motion``, padded by ``max_lag`` after each (as far as the record goes) so the
    arm's catching up is inside."""
    moving = (np.abs(qd) > opts.motion_speed).any(axis=1)
    pad = int(np.ceil(opts.max_lag / dt))
    shortest = max(3, int(round(opts.min_motion / dt)))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], moving.astype(int), [0]])))
    out: list[tuple[int, int]] = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a < shortest:  # a record cut mid-motion keeps its last stretch
            continue
        a, b = max(a, pad), min(b + pad, len(qd))
        if b - a < shortest:
            continue
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def best_shift(t: np.ndarray, q_fb: np.ndarray, cmd: CubicHermiteSpline, max_lag: float) -> float:
    """The shift ``tau`` [s] in [0, max_lag] best aligning ``q_cmd(t - tau)`` (plus an offset)
    with ``q_fb(t)`` for one joint, ``cmd`` its commanded path (grid at 0.5 ms, then a bounded
    scalar search)."""

    def cost(tau: float) -> float:
        e = q_fb - cmd(t - tau)
        e = e - e.mean()
        return float(e @ e)

    taus = np.arange(0.0, max_lag + 1e-12, 0.0005)
    costs = np.array([cost(x) for x in taus])
    k = int(np.argmin(costs))
    lo, hi = taus[max(k - 1, 0)], taus[min(k + 1, len(taus) - 1)]
    if hi <= lo:
        return float(taus[k])
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    return float(res.x)


def held_peak(
    q: np.ndarray, dt: float, order: int, opts: DynamicsOptions, ignore: np.ndarray | None = None
) -> float:
    """Largest ``|d^order q / dt^order|`` held for ``opts.hold`` (Savitzky-Golay, cubic),
    samples where ``ignore`` (bool, same length) is set not counting."""
    window = opts.accel_window if order == 2 else opts.jerk_window
    n = max(order + 2, int(round(window / dt)) | 1)
    if len(q) < n:
        return float("nan")
    d = np.abs(savgol_filter(q, n, 3 if order <= 3 else order, deriv=order, delta=dt))
    if ignore is not None:
        d[ignore] = 0.0
    held = minimum_filter1d(d, max(1, int(round(opts.hold / dt))), mode="nearest")
    return float(held.max())


def estimate_from_record(
    path: str, opts: DynamicsOptions = DynamicsOptions(), cycle: float | None = None
) -> DynamicsEstimate:
    """:func:`estimate_dynamics` on the ``egm`` table of the flight record at ``path``, timed by
    the controller's clock (:func:`egm_arrays`)."""
    rows = egm_arrays(path, cycle)
    return estimate_dynamics(
        rows.t, rows.q_fb, rows.q_cmd, rows.qd_cmd, opts, str(path), rows.cycle
    )
