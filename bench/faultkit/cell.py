"""A simulated cell around the real daemon: ``thinkfast-run``, a fault controller, zenoh peers.

:class:`Cell` starts the daemon through :func:`thinkfast.sim.realtime.start_daemon` (loopback
ports picked free), a :class:`~bench.faultkit.monitor.Monitor` on a zenoh session of its
own, a detection publisher on another session (it may close and reopen), and the
:class:`~bench.faultkit.controller.FaultController`. Throws come from
:mod:`thinkfast.sim.throws`, seen by the camera model and published in real time by
:func:`thinkfast.sim.realtime.publish_throw`; each is judged against the controller's arm.
:meth:`Cell.check` runs the :class:`~bench.faultkit.checker.ReplyChecker` over every cycle
and :meth:`Cell.process_failures` checks the process (alive, stderr, exit status).
"""

from __future__ import annotations

import dataclasses
import re
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bench.faultkit import rows as R
from bench.faultkit.checker import ReplyChecker
from bench.faultkit.monitor import Monitor
from bench.faultkit.probe import StallProbe, attribute, rss_mb
from bench.faultkit.remote import RemoteController
from bench.faultkit.senders import free_udp_port
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.realtime import (
    RealtimeResult,
    daemon_log,
    judge_throw,
    publish_throw,
    start_daemon,
    stop_daemon,
    throw_rng,
    wait_port,
)
from thinkfast.sim.throws import Throw, plane_crossing

LEAD = 0.2  # s from a throw's start to its first detection's capture
_BAD = re.compile(r"Traceback|\bException\b")


@dataclasses.dataclass
class Context:
    """What every scenario shares: tree, robot, camera, seed, stall probe, progress output."""

    tree: Path
    robot: object
    kin: object
    extrinsic: object
    camera: object
    seed: int = 1
    daemon_opts: tuple[str, ...] = ()
    log: object = print
    record_dir: Path | None = None  # every cell records there (``--record``) unless told
    resync_s: float = 0.02  # a controller silence longer than this wants a resync [s]
    controller_fifo: int | None = 30  # SCHED_FIFO priority of the controller's loop, if allowed


class ThrowOutcome(NamedTuple):
    """One throw through the cell: verdict, wall times [s] and what the daemon did meanwhile."""

    result: RealtimeResult
    t_first: float  # first frame with the ball in the hand
    t0: float  # release
    t_cross: float  # centre crosses the plane
    modes: list[str]  # daemon modes from the first frame to the crossing
    executed: bool  # it moved for this throw ("executing" seen)


class Cell:
    """The daemon with its simulated surroundings (see the module doc).

    Args:
        ctx: shared context. planner: ``tree`` or ``naive``. servo: the controller's servo model.
        record: ``--record`` target. extra: more daemon options. preexec_fn: run in the daemon's
        process before it starts. seed: the controller's fault randomness.
    """

    def __init__(self, ctx: Context, planner="tree", servo=ServoConfig(), record=None, extra=(),
                 preexec_fn=None, seed=0):  # fmt: skip
        self.ctx, self.planner, self.servo, self.seed = ctx, planner, servo, seed
        self.prefix = f"faults{id(self) % 100000}_{int(time.time() * 1e3) % 100000}"
        if record is None and ctx.record_dir is not None:
            record = Path(ctx.record_dir) / f"{self.prefix}.h5"
        self.record, self.extra, self.preexec_fn = record, tuple(extra), preexec_fn
        self.egm_port, self.zport = free_udp_port(), free_tcp_port()
        self.endpoint = f"tcp/127.0.0.1:{self.zport}"
        self.proc: subprocess.Popen | None = None
        self.ctl: RemoteController | None = None
        self.mon_session = self.pub_session = None
        self.monitor: Monitor | None = None
        self.checker = ReplyChecker(ctx.robot, silence=ctx.resync_s)
        self._pending = np.zeros((0, R.NCOL))
        self.exit_code: int | None = None
        self.t_exit: float | None = None
        self.alive_until_stop = True
        self.signalled = False
        self.t_start = time.time()
        self.probe: StallProbe | None = None
        self.stalls = np.zeros((0, 2))
        self.published = 0  # detections of throws published
        self.keep_rows = True  # keep every row for rows_between (off for long runs)
        self._kept: list[np.ndarray] = []

    def __enter__(self) -> Cell:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self, timeout: float = 60.0) -> Cell:
        """Start everything; on failure nothing is left running (the error is raised)."""
        try:
            return self._start(timeout)
        except BaseException:
            self.close()
            raise

    def _start(self, timeout: float) -> Cell:
        ctx = self.ctx
        self.probe = StallProbe()
        self.proc = start_daemon(ctx.tree, self.planner, self.egm_port, self.zport, self.prefix,
                                 self.record, None, ctx.daemon_opts + self.extra,
                                 preexec_fn=self.preexec_fn)  # fmt: skip
        wait_port(self.proc, self.zport, timeout)
        self.mon_session = open_peer(connect=[self.endpoint])
        self.monitor = Monitor(self.mon_session, self.prefix)
        if not self.monitor.wait_status(timeout):
            raise RuntimeError(f"no status from the daemon: {daemon_log(self.proc)[-500:]}")
        robot = ctx.robot
        limits = (robot.q_lower, robot.q_upper)
        target = ("127.0.0.1", self.egm_port)
        self.ctl = RemoteController(target, self.servo, robot.home, self.seed, q_limits=limits,
                                    fifo=ctx.controller_fifo)  # fmt: skip
        self.ctl.start()
        self.controller_rt = self.ctl.realtime
        self.open_publisher()
        deadline = time.time() + 10.0
        while self.ctl.last_cmd is None and time.time() < deadline:
            time.sleep(0.02)
        time.sleep(0.5)  # zenoh routes settle
        return self

    def open_publisher(self) -> None:
        self.pub_session = open_peer(connect=[self.endpoint])
        time.sleep(0.2)

    def close_publisher(self) -> None:
        session, self.pub_session = self.pub_session, None
        if session is not None:
            session.close()

    def alive(self) -> bool:
        """The daemon runs (a death before :meth:`stop` or :meth:`send_signal` is remembered)."""
        alive = self.proc is not None and self.proc.poll() is None
        if not self.signalled:
            self.alive_until_stop &= alive
        return alive

    def send_signal(self, sig) -> None:
        """Signal the daemon on purpose (its exit is then no crash)."""
        self.alive()
        self.signalled = True
        self.proc.send_signal(sig)

    # ------------------------------------------------------------------ throws
    def throw(self, th: Throw, i: int, hooks=(), settle: float = 4.0, stop=None) -> ThrowOutcome:
        """Publish throw ``th`` (camera noise ``i``), run ``hooks`` (``(seconds after release,
        fn)``) meanwhile, judge it, then wait for the daemon's ``idle`` (at most ``settle`` s).

        ``stop``: an event that ends the publishing early (a hook may then close the session).
        """
        t_first = time.time() + LEAD
        t0 = t_first + th.t_release
        timers = [threading.Timer(max(0.0, t0 + dt - time.time()), fn) for dt, fn in hooks]
        for tm in timers:
            tm.daemon = True
            tm.start()
        try:
            rep = publish_throw(self.pub_session, self.prefix, th, throw_rng(self.ctx.seed, i),
                                self.ctx.extrinsic, t0, self.ctx.camera, stop)  # fmt: skip
            self.published += rep.sent
        except Exception:
            if stop is None or not stop.is_set():
                raise
        t_cross = t0 + plane_crossing(th).t
        time.sleep(max(0.0, t_cross + 0.3 - time.time()))
        t_hist, q_hist = self.ctl.history(t_first - 1.0)
        result = judge_throw(th, t_hist, q_hist, self.ctx.kin, t0)
        modes = self.monitor.modes_between(t_first, t_cross)
        self.monitor.wait_state("idle", settle)
        for tm in timers:
            tm.join(1.0)
        self.alive()
        return ThrowOutcome(result, t_first, t0, t_cross, modes, "executing" in modes)

    # ------------------------------------------------------------------ stop and checks
    def stop(self, sig=signal.SIGINT, timeout: float = 20.0) -> int | None:
        """Signal the daemon (the controller keeps talking while it brakes); wait; stop the rest."""
        if self.proc is not None and self.exit_code is None:
            if self.alive():
                self.signalled = True  # its exit is then no crash
            self.exit_code = stop_daemon(self.proc, sig, timeout)
            self.t_exit = time.time()
        self.close()
        return self.exit_code

    def close(self) -> None:
        """Stop the controller and the sessions (idempotent); kill a daemon still running."""
        if self.ctl is not None:
            self.ctl.stop()
        if self.probe is not None:
            self.stalls, self.probe = self.probe.stop(), None
        for s in (self.pub_session, self.mon_session):
            if s is not None:
                try:
                    s.close()
                except Exception:
                    pass
        self.pub_session = self.mon_session = None
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def feed(self) -> None:
        """Hand the controller's rows older than 0.5 s to the checker (long runs, as they go)."""
        rows = np.vstack([self._pending, self._take()])
        cut = int(np.searchsorted(rows[:, R.T_SEND], time.time() - 0.5))
        self._pending = rows[cut:]
        self.checker.feed(rows[:cut], self.monitor.braking)

    def _take(self) -> np.ndarray:
        rows = self.ctl.rows.take()
        if self.keep_rows:
            self._kept.append(rows)
        return rows

    def rows_between(self, t0: float, t1: float) -> np.ndarray:
        """The controller's rows of cycles sent between wall times ``t0`` and ``t1`` [s]."""
        self._pending = np.vstack([self._pending, self._take()])
        rows = np.vstack(self._kept) if self._kept else np.zeros((0, R.NCOL))
        return rows[(rows[:, R.T_SEND] >= t0) & (rows[:, R.T_SEND] < t1)]

    def check(self) -> tuple[dict, list[str]]:
        """The checker's figures and failures over every cycle so far (call after :meth:`stop`)."""
        rows = np.vstack([self._pending, self._take()])
        self._pending = np.zeros((0, R.NCOL))
        if self.t_exit is not None:  # the daemon is gone: cycles sent after it exited are no test
            last = np.flatnonzero(rows[:, R.N_VALID] > 0)
            rows = rows[: last[-1] + 1] if len(last) else rows[:0]
        self.checker.feed(rows, self.monitor.braking)
        fig = self.checker.summary()
        fig.update(attribute(self.checker.missed_times, self.checker.missed_late, self.stalls))
        t = self.checker.worst_brake_jerk_at
        if self.checker.f["jerk_ratio_brake"] > self.checker.jerk_tol:  # where: the daemon's modes
            fig["worst_brake_jerk_modes"] = sorted(self.monitor.modes_between(t - 0.1, t + 0.02))
        return fig, self.checker.failures()

    def process_failures(self, expect_exit0: bool = True) -> list[str]:
        """Crash, non-zero exit, exception or traceback on stderr, a latched fault."""
        out = []
        if not self.alive_until_stop:
            out.append(f"daemon died (exit {self.proc.returncode})")
        if expect_exit0 and self.exit_code != 0:
            out.append(f"exit status {self.exit_code}")
        err = daemon_log(self.proc) if self.proc is not None else ""
        if _BAD.search(err):
            line = next(ln for ln in err.splitlines() if _BAD.search(ln))
            out.append(f"stderr: {line.strip()[:120]}")
        return out

    def status(self) -> dict:
        return dict(self.monitor.last or {}) if self.monitor else {}

    def rss_mb(self) -> float | None:
        """The daemon's resident memory [MB] (Linux /proc), None when unknown."""
        return rss_mb(self.proc.pid) if self.proc is not None else None
