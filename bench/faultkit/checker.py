"""Independent checks of the commands a controller applied, cycle by cycle on its own clock.

Input: the fault controller's rows (:mod:`bench.faultkit.rows`): per 4 ms cycle, what it
sent and the last valid ``EgmSensor`` that arrived during the cycle (decoded with the campaign's
own protobuf classes). A cycle without a reply keeps the previous command. Finite differences
(``dt`` = 4 ms) are taken only inside runs of consecutive cycles (``tm`` steps of exactly 4 ms: a
pause, a silence or a stall of this process breaks the run). A window is *clean* when every
cycle in it had a fresh reply: one reply (or one per copy sent), and no missed cycle in it or in
the :data:`SETTLE` cycles before it. A controller cannot tell which ``EgmRobot`` a reply answers;
after a late reply the next ones may be one cycle stale until two arrive in one cycle, and the
commands it applies then jump by two cycles' motion. Such windows, and those with a missed
reply, count only in the ``*_all`` figures (the host or the daemon was late, see the stall
attribution).

Checks (relative tolerance ``rtol``; ratios are value / limit, per joint, the maximum reported):

* applied positions move at most ``v_max`` (first differences / dt) and accelerate at most
  ``a_max`` (second differences / dt^2); ``speedRef`` at most ``v_max``;
* while braking, third differences of positions / dt^3 (windows of four braking cycles) and
  second differences of ``speedRef`` / dt^2 (windows ending in a braking cycle: the change from
  the last acceleration before the brake counts) at most ``jerk_tol`` j_max; the jerk of normal
  running is reported as a figure;
* after a silence (``tm`` gap > ``silence``) and at the first reply, the first applied command
  lies within ``pos_tol`` of the measured position, moved along the measured velocity for at
  most one cycle (``q + s qd``, 0 <= s <= dt), and its ``speedRef`` is within ``a_max dt`` of the
  measured velocity (what one cycle at the acceleration limit can change). The first
  :data:`RESYNC_WAIT` cycles after a silence may go unanswered by design (the daemon waits for
  three packets to measure the velocity): counted in ``missed_after_silence``, not in
  ``missed`` nor in the cycles of ``answered_pct``; a further miss counts as usual, and the
  reply after it may answer the packet before it (arrived a cycle late): it is then checked
  against that packet's measured state (``resyncs_late``);
* every reply finite and inside the URDF limits;
* no more valid replies than requests sent (``extra_replies``: replies to something else, such
  as a malformed datagram), counted from the controller's first request: a first reply that
  arrives a cycle late lands in the cycle of the second request, beside that one's reply.

:meth:`ReplyChecker.feed` takes rows in batches (the soak feeds it every few seconds).
"""

from __future__ import annotations

import numpy as np

from bench.faultkit import rows as R

SETTLE = 4  # cycles after a missed one whose replies may be stale
RESYNC_WAIT = 2  # cycles after a silence that may go unanswered by design
MAX_LATE = 25  # missed cycles after those whose packets a late first reply may answer


class ReplyChecker:
    """Accumulates the checks over batches of rows (see the module doc).

    Args:
        limits: object with ``q_lower, q_upper, v_max, a_max, j_max`` (6,) each (a loaded robot).
        dt: controller cycle [s].
        rtol: relative tolerance of the velocity and acceleration checks.
        jerk_tol: allowed jerk ratio while braking.
        silence: a ``tm`` gap longer than this [s] is a silence (resync expected).
        pos_tol: resync position tolerance [rad].
    """

    def __init__(self, limits, dt=0.004, rtol=1e-3, jerk_tol=1.05, silence=0.02, pos_tol=1e-3):
        self.lim = limits
        self.dt, self.rtol, self.jerk_tol, self.silence, self.pos_tol = (
            dt, rtol, jerk_tol, silence, pos_tol,
        )  # fmt: skip
        self.ctx = np.zeros((0, R.NCOL))  # the last 3 rows of the previous batch
        self.ctx_brake = self.ctx_has = np.zeros(0, dtype=bool)
        self.started = False
        self.f = dict.fromkeys(
            ("v_ratio", "v_ratio_all", "a_ratio", "a_ratio_all", "speedref_ratio",
             "jerk_ratio_brake", "speedref_jerk_ratio_brake", "jerk_ratio_normal",
             "resync_pos_err_mrad", "resync_vel_ratio"), 0.0,
        )  # fmt: skip
        self.n = dict.fromkeys(
            ("cycles", "replied", "missed", "bad_replies", "nonfinite", "outside_urdf",
             "extra_replies", "gaps", "silences", "resyncs_checked", "resyncs_late",
             "resync_unanswered", "missed_after_silence",
             "brake_cycles", "v_violations", "a_violations", "jerk_violations", "restarts"), 0,
        )  # fmt: skip
        self.missed_times: list[float] = []  # t_send of cycles without a reply
        self.missed_late: int = 0  # ... of which this process sent late (its own stall)
        self.worst_a_at = float("nan")
        self.worst_brake_jerk_at = float("nan")  # send time of the worst braking jerk window
        self.resync_fail: list[dict] = []
        self.resyncs: list[dict] = []  # every resync checked (at most 1000)
        self._pending_resync = True  # the first reply is a resync too
        self._seen_reply = False
        self._waited = 0
        self._replies = self._copies = 0
        self._since: list[np.ndarray] = []  # rows since the last silence, while unanswered
        self._offsets = np.zeros(0)  # send time - reply header time [s], on-time replies

    def feed(self, rows: np.ndarray, braking=None) -> None:
        """Check a batch of rows (in cycle order); ``braking(rows)`` -> bool (N,) (None: never)."""
        if len(rows) == 0:
            return
        br_new = np.zeros(len(rows), dtype=bool) if braking is None else braking(rows)
        allr = np.vstack([self.ctx, rows])
        brake = np.r_[self.ctx_brake, br_new]
        has = np.r_[self.ctx_has, rows[:, R.N_VALID] > 0]
        copies = _copies(allr)
        fresh = has & (allr[:, R.N_VALID] <= copies)
        missed = ~has
        for s in range(1, SETTLE + 1):
            fresh[s:] &= ~missed[:-s]
        new = np.zeros(len(allr), dtype=bool)
        new[len(self.ctx) :] = True
        counted_from = self._count(rows)
        self._resyncs(rows, counted_from)
        q, qd = self._applied(allr, has | ~np.isnan(allr[:, R.CMD_Q.start]))
        gap = np.r_[True, np.diff(allr[:, R.K]) != 1] | self._restarts(allr, q, qd, new)
        self._differences(allr, q, qd, fresh, gap, brake, new)
        keep = slice(max(0, len(allr) - 3), len(allr))
        self.ctx, self.ctx_brake, self.ctx_has = allr[keep].copy(), brake[keep], has[keep]
        self.ctx[:, R.CMD_Q], self.ctx[:, R.CMD_QD] = q[keep], qd[keep]  # forward-filled

    # ------------------------------------------------------------------ pieces
    def _restarts(self, allr: np.ndarray, q: np.ndarray, qd: np.ndarray, new) -> np.ndarray:
        """Cycles where the command jumps to the measured position at rest: the daemon restarts
        from the feedback (after a fault, once the arm stands); that cannot move the arm, so no
        finite difference is taken across it. Counted in ``restarts``."""
        lim, dt = self.lim, self.dt
        step = np.abs(np.diff(q, axis=0)) > lim.v_max * dt * (1 + self.rtol)
        jump = np.r_[False, step.any(axis=1)]
        at_rest = (np.abs(qd) < 1e-9).all(axis=1)
        measured = (np.abs(q - allr[:, R.Q_SENT]) <= self.pos_tol).all(axis=1)
        restart = jump & at_rest & measured
        self.n["restarts"] += int((restart & new).sum())
        return restart

    def _count(self, rows: np.ndarray) -> int:
        """Count the batch's cycles from the first reply ever on; returns the index of the
        first row counted."""
        n = self.n
        # every request the controller sent counts towards the replies it may receive, those
        # before the first reply too: that reply may answer one of them, arriving a cycle late
        valid = rows[:, R.N_VALID]
        self._replies += int(valid.sum())
        self._copies += int(_copies(rows).sum())
        n["extra_replies"] = max(0, self._replies - self._copies)  # replies to something else
        if not self.started:
            first = np.flatnonzero(valid > 0)
            if len(first) == 0:
                return len(rows)
            rows, valid = rows[first[0] :], valid[first[0] :]
            self.started = True
            counted_from = int(first[0])
        else:
            counted_from = 0
        n["cycles"] += len(rows)
        n["replied"] += int((valid > 0).sum())
        miss = valid == 0
        n["missed"] += int(miss.sum())
        self.missed_times.extend(rows[miss, R.T_SEND].tolist())
        self.missed_late += int((miss & (rows[:, R.FLAGS].astype(int) & R.LATE > 0)).sum())
        n["bad_replies"] += int(rows[:, R.N_BAD].sum())
        n["nonfinite"] += int(rows[:, R.N_NONFINITE].sum())
        lo, hi = self.lim.q_lower, self.lim.q_upper
        applied_out = ((rows[:, R.CMD_Q] < lo) | (rows[:, R.CMD_Q] > hi)).any(axis=1)
        # replies outside the URDF limits: every reply as counted by the controller, or the
        # applied one as checked here (NaN compares False: cycles without a reply count 0)
        n["outside_urdf"] += int(np.maximum(rows[:, R.N_OUTSIDE], applied_out).sum())
        cmd = rows[valid > 0][:, R.CMD_Q]
        if len(cmd):
            sr = np.abs(rows[valid > 0][:, R.CMD_QD]) / self.lim.v_max
            self.f["speedref_ratio"] = max(self.f["speedref_ratio"], float(sr.max()))
        return counted_from

    def _resyncs(self, rows: np.ndarray, counted_from: int) -> None:
        """First applied command after each silence (and the first ever): at the measured state."""
        k = rows[:, R.K]
        prev_k = self.ctx[-1, R.K] if len(self.ctx) else np.nan
        dk = np.diff(np.r_[prev_k, k])
        silence = np.nan_to_num(dk, nan=0.0) * self.dt > self.silence + 1e-9
        self.n["gaps"] += int((np.nan_to_num(dk, nan=1.0) > 1).sum())
        self.n["silences"] += int(silence.sum())
        self._tm_offsets(rows)
        pending, seen, waited = self._pending_resync, self._seen_reply, self._waited
        since = self._since
        for i in range(len(rows)):
            if silence[i]:
                if pending and seen and waited >= 5:  # 5 cycles sent after a silence, no reply
                    self.n["resync_unanswered"] += 1
                pending, waited = True, 0
                since.clear()
            if pending and seen and waited < RESYNC_WAIT and rows[i, R.N_VALID] == 0:
                self._excuse(rows[i], i >= counted_from)
            if pending and rows[i, R.N_VALID] > 0:
                # after missed cycles the reply may answer one of their packets (a late reply)
                pending, seen = False, True
                self._check_resync(rows[i], since[RESYNC_WAIT:])
                since.clear()
            elif pending:
                since.append(rows[i].copy())
                if len(since) > MAX_LATE + RESYNC_WAIT:  # keep the newest: a late reply
                    del since[RESYNC_WAIT]  # answers a recent packet
            waited += 1
        self._pending_resync, self._seen_reply, self._waited = pending, seen, waited

    def _tm_offsets(self, rows: np.ndarray) -> None:
        """Keep samples of send time minus the reply's header time (the daemon stamps a reply
        with the time it received the packet, in ms of its own clock) from cycles answered on
        time, to tell which packet a late reply answered (diagnostics only)."""
        ok = (rows[:, R.N_VALID] == 1) & np.isfinite(rows[:, R.R_TM])
        if ok.any():
            d = rows[ok, R.T_SEND] - rows[ok, R.R_TM] / 1000.0
            self._offsets = np.r_[self._offsets, d][-200:]

    def _excuse(self, row: np.ndarray, counted: bool) -> None:
        """A cycle right after a silence went unanswered by design: not a missed reply."""
        self.n["missed_after_silence"] += 1
        if not counted:
            return
        self.n["missed"] -= 1
        self.n["cycles"] -= 1
        t = float(row[R.T_SEND])
        for j in range(len(self.missed_times) - 1, -1, -1):
            if self.missed_times[j] == t:
                del self.missed_times[j]
                break
        if int(row[R.FLAGS]) & R.LATE:
            self.missed_late -= 1

    def _resync_error(self, row: np.ndarray, state: np.ndarray) -> tuple[float, float]:
        """(position error [rad], speedRef error / (a_max dt)) of ``row``'s command against the
        measured state of ``state`` (a row)."""
        q_meas, qd_meas = state[R.Q_TRUE], state[R.QD_TRUE]
        q, qd = row[R.CMD_Q], row[R.CMD_QD]
        # distance to the segment q_meas + s qd_meas, 0 <= s <= dt (per joint)
        step = qd_meas * self.dt
        s = np.clip(np.where(step != 0, (q - q_meas) / np.where(step != 0, step, 1), 0), 0, 1)
        pos_err = float(np.max(np.abs(q - (q_meas + s * step))))
        vel_ratio = float(np.max(np.abs(qd - qd_meas) / (self.lim.a_max * self.dt)))
        return pos_err, vel_ratio

    def _check_resync(self, row: np.ndarray, before=()) -> None:
        """The first command after a silence against the state measured in its cycle, or in one
        of the cycles before it that went unanswered beyond :data:`RESYNC_WAIT` (``before``:
        their rows, at most :data:`MAX_LATE`): the reply may answer one of those packets and
        have arrived late (a stall of the host), as after any missed reply. Counted in
        ``resyncs_late``."""
        pos_err, vel_ratio = self._resync_error(row, row)
        late = 0
        for j, state in enumerate(before):
            e = self._resync_error(row, state)
            if max(e[0] / self.pos_tol, e[1]) < max(pos_err / self.pos_tol, vel_ratio):
                (pos_err, vel_ratio), late = e, len(before) - j
        self.n["resyncs_late"] += late > 0
        qd_meas = row[R.QD_TRUE]
        self.n["resyncs_checked"] += 1
        f = self.f
        f["resync_pos_err_mrad"] = max(f["resync_pos_err_mrad"], 1e3 * pos_err)
        f["resync_vel_ratio"] = max(f["resync_vel_ratio"], vel_ratio)
        rec = {
            "t": round(float(row[R.T_SEND]), 3),
            "pos_err_mrad": round(1e3 * pos_err, 3),
            "vel_ratio": round(vel_ratio, 3),
            "speed": round(float(np.abs(qd_meas).max()), 3),
            "late": late,  # cycles between the packet it matches best and its own
        }
        if len(self.resyncs) < 1000:
            self.resyncs.append(rec)
        if pos_err > self.pos_tol * (1 + self.rtol) or vel_ratio > 1 + self.rtol:
            if len(self.resync_fail) < 20:
                self.resync_fail.append({**rec, **self._context(row, list(before))})

    def _context(self, row: np.ndarray, before: list) -> dict:
        """Diagnostics of a failed resync: the cycles it could answer and the one its header
        time points to (offset from on-time replies), positions of the joint most off."""
        j = int(np.argmax(np.abs(row[R.CMD_Q] - row[R.Q_TRUE])))
        cycles = [*before, row]
        out = {
            "joint": j + 1,
            "cmd_q": round(float(row[R.CMD_Q][j]), 5),
            "cmd_qd": round(float(row[R.CMD_QD][j]), 4),
            "cycles": [
                {
                    "k": int(r[R.K]),
                    "q": round(float(r[R.Q_TRUE][j]), 5),
                    "qd": round(float(r[R.QD_TRUE][j]), 4),
                    "flags": int(r[R.FLAGS]),
                }
                for r in cycles
            ],  # fmt: skip
        }
        if len(self._offsets) and np.isfinite(row[R.R_TM]):
            rx = row[R.R_TM] / 1000.0 + float(np.median(self._offsets))  # on the sender's clock
            out["received_ms_after_send"] = [round(1e3 * (rx - r[R.T_SEND]), 1) for r in cycles]
        return out

    @staticmethod
    def _applied(allr: np.ndarray, src: np.ndarray):
        """Commands in force each cycle: the last reply's, forward-filled over missed cycles."""
        idx = np.maximum.accumulate(np.where(src, np.arange(len(allr)), -1))
        filled = (idx >= 0)[:, None]
        q = np.where(filled, allr[np.maximum(idx, 0)][:, R.CMD_Q], np.nan)
        qd = np.where(filled, allr[np.maximum(idx, 0)][:, R.CMD_QD], np.nan)
        return q, qd

    def _differences(self, allr, q, qd, has, gap, brake, new) -> None:
        dt, lim, f, n, tol = self.dt, self.lim, self.f, self.n, 1 + self.rtol
        n["brake_cycles"] += int((brake & new).sum())
        for order, key, scale in ((1, "v", lim.v_max), (2, "a", lim.a_max), (3, "j", lim.j_max)):
            m = len(allr) - order
            if m <= 0:
                continue
            d = np.diff(q, n=order, axis=0) / dt**order / scale  # window ends at i + order
            ok = ~np.isnan(d).any(axis=1) & new[order:]
            clean = ok.copy()
            for s in range(order + 1):
                sl = slice(s, s + m)
                clean &= has[sl]
                if s > 0:
                    ok &= ~gap[sl]
                    clean &= ~gap[sl]
            r = np.abs(d).max(axis=1)
            if key == "v":
                f["v_ratio"] = max(f["v_ratio"], _max(r[clean]))
                f["v_ratio_all"] = max(f["v_ratio_all"], _max(r[ok]))
                n["v_violations"] += int((r[clean] > tol).sum())
            elif key == "a":
                f["a_ratio_all"] = max(f["a_ratio_all"], _max(r[ok]))
                if _max(r[clean]) > f["a_ratio"]:
                    f["a_ratio"] = _max(r[clean])
                    self.worst_a_at = float(allr[order:][clean][np.argmax(r[clean]), R.T_SEND])
                n["a_violations"] += int((r[clean] > tol).sum())
            else:  # all four cycles braking (the entry is judged on speedRef below)
                b = brake[3:] & brake[2:-1] & brake[1:-2] & brake[:-3]
                cb = clean & b
                if _max(r[cb]) > f["jerk_ratio_brake"]:
                    f["jerk_ratio_brake"] = _max(r[cb])
                    self.worst_brake_jerk_at = float(allr[order:][cb][np.argmax(r[cb]), R.T_SEND])
                f["jerk_ratio_normal"] = max(f["jerk_ratio_normal"], _max(r[clean & ~b]))
                n["jerk_violations"] += int((r[cb] > self.jerk_tol).sum())
            if key == "a":  # second differences of speedRef ending in a braking cycle
                rr = (np.abs(np.diff(qd, n=2, axis=0)) / dt**2 / lim.j_max).max(axis=1)
                sel = clean & brake[order:]
                f["speedref_jerk_ratio_brake"] = max(f["speedref_jerk_ratio_brake"], _max(rr[sel]))

    # ------------------------------------------------------------------ results
    def summary(self) -> dict:
        """Figures (rounded) and counts."""
        out = {k: round(v, 4) for k, v in self.f.items()}
        out.update(self.n)
        c = self.n["cycles"]
        out["answered_pct"] = round(100.0 * self.n["replied"] / c, 4) if c else None
        out["missed_own_stall"] = self.missed_late
        if self.resync_fail:
            out["resync_failures"] = self.resync_fail
        return out

    def failures(self) -> list[str]:
        """What broke a limit (empty: the commands passed every check)."""
        f, n, tol, out = self.f, self.n, 1 + self.rtol, []
        for key, what in (("v_ratio", "velocity"), ("a_ratio", "acceleration"),
                          ("speedref_ratio", "speedRef")):  # fmt: skip
            if f[key] > tol:
                out.append(f"{what} {f[key]:.3f} x limit")
        for key in ("jerk_ratio_brake", "speedref_jerk_ratio_brake"):
            if f[key] > self.jerk_tol:
                out.append(f"{key} {f[key]:.2f}")
        if self.resync_fail:
            out.append(f"{len(self.resync_fail)} resync(s) off the measured state")
        for key in ("nonfinite", "outside_urdf", "bad_replies", "resync_unanswered"):
            if n[key]:
                out.append(f"{n[key]} {key}")
        return out


def _copies(rows: np.ndarray) -> np.ndarray:
    """Requests sent per cycle: 2 where the ``EgmRobot`` went twice, else 1."""
    return np.where(rows[:, R.FLAGS].astype(int) & R.DUP, 2, 1)


def _max(a: np.ndarray) -> float:
    return float(a.max()) if a.size else 0.0
