"""The isolated EGM reply loop: a process of its own that no planning can delay.

Started by the daemon with ``--reply-process`` (:mod:`thinkfast.daemon.planner_process`, the planner
process), it alone owns the EGM socket, and ``--cpu``/``--fifo`` apply to it alone. Its loop
does, per ``EgmRobot``: receive, check the peer and the feedback, place the packet on the
controller's clock, evaluate the current plan at that time, supervise, encode, send
(:class:`~thinkfast.control.core.ControlCore` around a
:class:`~thinkfast.control.plan.PlanFollower`: the same catch-up, restart, standby and fault
policy as the daemon's own loop). Between packets it writes each reply's row to the ring the
planner reads (:mod:`thinkfast.reply.rows`), takes a new plan from shared memory (a
seqlock: never waits) and prepares the next reply at once (the setpoint and the supervisor's
filter for the next cycle, its ``EgmSensor`` body encoded; again after a new plan: the follower
forgets the one prepared, :meth:`PlanFollower.retract`), so that a packet finds its reply
ready: decode, the feedback checks, the clock, commit, the header, send. It keeps the
deadlines:

* a heartbeat older than ``[safety] planner_timeout``: the plan is replaced by the supervisor's
  jerk-limited stop (brake ``planner_stale``); once stopped and the planner speaks again, the
  loop plans on from the commanded state (a ``resync`` the planner makes too) and resumes;
* the planner process gone (this process was re-parented): brake ``planner_lost``, one line on
  stderr, a status of its own on zenoh (:mod:`thinkfast.reply.orphan_status`: ``state``
  ``fault``), and the loop keeps answering, holding the arm, until it is stopped (SIGTERM/SIGINT:
  it brakes while the controller still talks, then ends, as the daemon does).

No zenoh, no recorder, no logging inside the loop.
"""

from __future__ import annotations

import math
import os
import select
import signal
import sys
import time

import numpy as np

from thinkfast.contract.egm import EgmEncodeError, sensor_body
from thinkfast.control.core import ControlCore
from thinkfast.control.link import Feedback
from thinkfast.control.plan import SIZE, PlanFollower, decode_plan
from thinkfast.control.safety import SafetySupervisor, robot_limits
from thinkfast.link import gc_rule
from thinkfast.link.cycle import Cycle
from thinkfast.link.egm import open_egm
from thinkfast.link.egm_server import EgmServer
from thinkfast.link.registry import LinkSpec
from thinkfast.link.rt_thread import pin_thread, set_fifo
from thinkfast.reply import orphan_status
from thinkfast.reply.rows import WIDTH, call_row, event_row, reply_row
from thinkfast.reply.shared_plan import RowRing, Seqlock

PARENT_CHECK = 0.001  # s: how often the loop looks whether its planner process is still there


class ReplyLoop:
    """The reply process's state (module doc).

    Args:
        link: the EGM link (its reply function is :meth:`reply`).
        robot, cfg: the robot and the run configuration.
        plan: the plan seqlock (attached). ring: the row ring (attached).
        parent: the planner process's pid.
    """

    def __init__(self, robot, cfg, plan: Seqlock, ring: RowRing, parent: int):
        self.cfg, self.plan, self.ring, self.parent = cfg, plan, ring, parent
        self.timeout = cfg.safety.planner_timeout
        self.follower = PlanFollower(robot, cfg)
        sup = SafetySupervisor(robot_limits(robot, cfg.safety.position_margin), cfg.safety,
                               robot.home)  # fmt: skip
        self.events: list[np.ndarray] = []
        self.core = ControlCore(self.follower, sup, cfg.safety, on_event=self._on_event)
        self.link: EgmServer | None = None
        self.zenoh: tuple[str, str] | None = None  # (JSON5 config, key prefix): orphan status
        self.version = -1  # the plan block's version last read
        self.lost = False
        self.stop = False
        self._fb = None
        self._now = 0.0
        self._body: tuple | None = None  # (q, qd, sensor_body) of the reply prepared ahead
        self._parent_checked = -math.inf  # monotonic time the parent was last looked at [s]

    def _on_event(self, t: float, kind: str, detail: dict) -> None:
        self.events.append(event_row(t, kind, detail.get("reason")))

    def reply(self, fb: Feedback, before: Feedback | None = None):
        """The link's reply function: the core's reply to ``fb`` (None: unanswered)."""
        now = time.time()
        late = self.link.behind
        r = self.core.on_feedback(fb, now, before, late)
        self._fb, self._now = fb, now
        if r is None:
            return None
        body = self._body
        if body is not None and r.q is body[0] and r.qd is body[1]:
            return body  # the prepared reply (the same read-only arrays): encoded already
        return r.q, r.qd

    def between(self, replied: bool, now_mono: float) -> None:
        """The work between two packets: the rows of the last one (:meth:`after`), a new plan
        and the deadlines (:meth:`watch_plan`, at ``now_mono`` [s]), then the next reply
        prepared ahead (:meth:`ControlCore.prepare`: again after a new plan) and its
        ``EgmSensor`` body encoded, so that a packet finds its reply ready."""
        core = self.core
        core.settle()  # the last feedback's velocity: left for after its reply
        if replied or self.events or self.follower.calls:
            self.after(replied)
        self.watch_plan(now_mono)
        core.prepare()
        ahead = core.prepared
        if ahead is None or ahead.result is None:
            self._body = None
        elif self._body is None or self._body[0] is not ahead.result[0]:
            q, qd = ahead.result[0], ahead.result[1]
            try:
                self._body = (q, qd, sensor_body(q, qd))
            except EgmEncodeError:  # the reply will say so (counted by the server)
                self._body = None

    def after(self, replied: bool) -> None:
        """Rows for the planner: the calls and events of the last packet, then its reply."""
        ring, f = self.ring, self.follower
        for name, t, q, qd, qdd in f.calls:
            ring.put(call_row(name, t, q, qd, qdd))
        f.calls.clear()
        for row in self.events:
            ring.put(row)
        self.events.clear()
        if replied and self.core.last is not None:
            stepped = f.t_set == self.core.last.tick.t
            ring.put(reply_row(self.core, f, self._fb, self.link, self._now, stepped))

    def watch_plan(self, now_mono: float) -> None:
        """Take a new plan; keep the deadlines (module doc)."""
        core, sup = self.core, self.core.sup
        if self.plan.version != self.version:
            got = self.plan.read()
            if got is not None:
                self.version = got[0]
                plan = decode_plan(got[1])
                following = self.follower.segments
                if plan is not None and self.follower.takes(plan):
                    core.invalidate()  # first: the follower forgets the reply prepared ahead
                    self.follower.adopt(plan)
                    self._join_late(plan, following)
        if self.lost or self._parent_lost(now_mono):
            return
        beat = self.plan.heartbeat
        stale = math.isfinite(beat) and now_mono - beat > self.timeout
        if stale and not sup.braking:
            core.brake("planner_stale")
            core.invalidate()
            self.events.append(event_row(core.clock.t, "planner_stale", "planner_stale"))
        elif not stale and sup.brake_reason == "planner_stale" and sup.stopped:
            core.invalidate()
            sup.release()  # the planner speaks again: plan on from where the arm stopped
            z = np.zeros(len(sup.q))
            self.follower.resync(np.array(sup.q), z, z, core.clock.t)
            self.events.append(event_row(core.clock.t, "planner_resumed"))

    def _parent_lost(self, now_mono: float) -> bool:
        """The planner process is gone (looked at every :data:`PARENT_CHECK` at most): brake
        ``planner_lost``, say so and publish a status of our own (module doc)."""
        if now_mono < self._parent_checked + PARENT_CHECK:
            return False
        self._parent_checked = now_mono
        if os.getppid() == self.parent:
            return False
        core = self.core
        self.lost = True
        core.brake("planner_lost")
        core.invalidate()
        self.events.append(event_row(core.clock.t, "planner_lost", "planner_lost"))
        msg = f"planner process {self.parent} lost: braking to a stop and holding"
        print(f"thinkfast reply process: {msg}; stop this process to end", file=sys.stderr)
        if self.zenoh is not None:  # the status goes on, from here
            orphan_status.start(*self.zenoh, self)
        return True

    def _join_late(self, plan, following) -> None:
        """A plan that starts at or before the last reply (the planner was late: a slow
        decision, a loaded host) is joined from the commanded state, with the same intent (a
        replan the planner makes too): the old plan was commanded past its start, and taking
        the new one at the next cycle would step its velocity by what the two plans drifted
        apart since. A segment followed already (``following``: the planner's copy of a replan
        made here, or a plan sent again for its wrist) is kept as it is."""
        core, sup, t = self.core, self.core.sup, self.core.clock.t
        seg = plan.segments[0]
        for later in plan.segments[1:]:
            if later.t0 <= t:
                seg = later
        if not math.isfinite(t) or seg.t0 > t or sup.braking:
            return
        if seg.traj is None and sup.stopped:
            return  # a hold from rest: nothing drifted
        for old in following:
            if old.t0 == seg.t0 and old.kind == seg.kind and np.array_equal(old.end, seg.end):
                return
        self.follower.timeline.segment = seg
        a_max = sup.limits.a_max
        qdd = np.clip(sup.qdd_end, -a_max, a_max)
        self.follower.resync(np.array(sup.q), np.array(sup.qd), qdd, core.clock.t)

    def run(self, spin_ahead: float = 0.0) -> None:
        """Serve until SIGTERM/SIGINT (module doc)."""
        egm, core = self.link, self.core
        poller = select.poll()
        poller.register(egm.fileno(), select.POLLIN)
        cycle = Cycle(self.cfg.safety.dt, spin_ahead)
        gc_rule.hold()  # collected between replies, never inside one
        last_rx = -math.inf
        while True:
            if self.stop:  # brake while the controller still talks, then end
                core.brake("signal")
                sup = core.sup
                if time.time() - last_rx > 0.1 or (sup.braking and sup.stopped):
                    break
            since = time.time() - last_rx
            replied = bool(poller.poll(cycle.wait_ms(since))) and egm.poll() > 0
            if replied:
                last_rx = time.time()
            self.between(replied, time.monotonic())
            if cycle.time_left(time.time() - last_rx) > 0.001:
                gc_rule.collect_due(oldest=1)


def main(conn, bind, controller, handover, robot, cfg, plan_name, ring_name, parent,
         cpu=None, fifo=None, spin_ahead=0.0, zenoh=None) -> None:  # fmt: skip
    """Body of the reply process: bind, report ``("ready", address, pid)`` (or ``("error",
    text)``) on the pipe ``conn``, then serve (module doc). ``zenoh``: (JSON5 configuration, key
    prefix) for a status of its own once the planner is lost (:mod:`orphan_status`)."""
    loop = ReplyLoop(robot, cfg, Seqlock(SIZE, plan_name), RowRing(WIDTH, name=ring_name), parent)
    loop.zenoh = zenoh
    if zenoh is not None:
        orphan_status.preload()  # never inside the loop (orphan_status.preload)

    def on_signal(signum, _frame):
        loop.stop = True

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    try:
        loop.link = open_egm(LinkSpec(bind, controller, handover, cfg.safety.dt), loop.reply)
        if cpu is not None:
            pin_thread(cpu)
        if fifo is not None:
            set_fifo(fifo)
    except Exception as exc:  # bind or real-time settings refused: the daemon says why
        conn.send(("error", str(exc)))
        return
    conn.send(("ready", loop.link.address, os.getpid()))
    conn.close()
    try:
        loop.run(spin_ahead)
    finally:
        loop.link.close()
        loop.plan.close()
        loop.ring.close()
    sys.stderr.flush()
    os._exit(0)  # no interpreter teardown: nothing is left to save, and it is slow and noisy
