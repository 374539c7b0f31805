"""The rows the reply process writes for the planner process (``--reply-process``).

One home for the layout of :class:`~thinkfast.reply.shared_plan.RowRing` rows: the reply
process writes them (:mod:`thinkfast.reply.process`), the planner process reads them
(:mod:`thinkfast.daemon.planner_process`). Three kinds, in the order things happened:

* ``CALL``: the reply loop planned again from the commanded state (``PlanFollower.CALLS``: a
  catch-up or supervisor change, a restart, a fault hold, a recovery); the planner makes the same
  call on its executor;
* ``EVENT``: something worth a log line (the control core's events and the deadlines');
* ``REPLY``: one reply: the controller time, the feedback, the command, the counters.
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.plan import CALLS, MODES
from thinkfast.control.safety import BRAKE_REASONS, KINDS
from thinkfast.link.egm_server import EgmCounters

REPLY, CALL, EVENT = 1.0, 2.0, 3.0
EVENTS = (
    "brake", "resync", "recover", "fault_latched", "controller_ready", "controller_standby",
    "planner_stale", "planner_resumed", "planner_lost",
)  # fmt: skip
CORE_COUNTS = ("held", "catch_ups", "repeats", "resyncs", "deferred", "standby_replies", "errors")
EGM_COUNTS = tuple(f.name for f in EgmCounters.__dataclass_fields__.values())
_SCALARS = (
    "type", "t", "seqno", "tm", "now", "work", "wait", "mode", "stepped", "brake", "ready",
    "standby", "latched", "plan_id", "epoch", "motors_on", "mci_running", "rapid_running",
    "peer_ip", "peer_port", "sup_ticks", "sup_intervened", "fault_count", "code", "reason",
)  # fmt: skip
COL = {name: k for k, name in enumerate(_SCALARS)}
_n = len(_SCALARS)
for _name in ("q_meas", "q", "qd", "qdd"):
    COL[_name] = slice(_n, _n + 6)
    _n += 6
for _name in CORE_COUNTS + EGM_COUNTS + tuple(f"kind_{k}" for k in KINDS):
    COL[_name] = _n
    _n += 1
WIDTH = _n


def call_row(name: str, t: float, q, qd, qdd) -> np.ndarray:
    """A ``CALL`` row: ``name`` of :data:`CALLS` at ``t`` [s] from ``q, qd, qdd`` (6,)."""
    row = np.full(WIDTH, np.nan)
    row[[COL["type"], COL["t"], COL["code"]]] = CALL, t, CALLS.index(name)
    row[COL["q"]], row[COL["qd"]], row[COL["qdd"]] = q, qd, qdd
    return row


def event_row(t: float, kind: str, reason: str | None = None) -> np.ndarray:
    """An ``EVENT`` row (``reason``: a brake reason, or None)."""
    row = np.full(WIDTH, np.nan)
    code = EVENTS.index(kind) if kind in EVENTS else -1
    row[[COL["type"], COL["t"], COL["code"]]] = EVENT, t, code
    row[COL["reason"]] = BRAKE_REASONS.index(reason) if reason in BRAKE_REASONS else -1
    return row


def reply_row(core, follower, fb, egm, now: float, stepped: bool) -> np.ndarray:
    """A ``REPLY`` row of the control ``core``'s last reply to feedback ``fb`` (received at
    ``now`` [s]) sent by the EGM server ``egm``."""
    row = np.zeros(WIDTH)
    sup, last, st = core.sup, core.last, dict(fb.state)  # EGM's motor, MCI and RAPID states
    timing = egm.timing
    k = (timing.count - 1) % len(timing.work_s) if timing is not None and timing.count else None
    peer = egm.peer
    ip = _ipv4(peer[0]) if peer is not None else -1.0
    mode = "standby" if last.mode == "standby" else core.mode()
    values = {
        "type": REPLY, "t": last.tick.t, "seqno": -1 if fb.cycle is None else fb.cycle,
        "tm": -1 if fb.t_ms is None else fb.t_ms, "now": now,
        "work": np.nan if k is None else timing.work_s[k],
        "wait": np.nan if k is None else timing.wait_s[k],
        "mode": MODES.index(mode) if mode in MODES else -1, "stepped": stepped,
        "brake": BRAKE_REASONS.index(sup.brake_reason) if sup.braking else -1,
        "ready": fb.ready, "standby": core.standby, "latched": core.latched,
        "plan_id": follower.plan_id, "epoch": follower.epoch, "motors_on": st["motors_on"],
        "mci_running": st["mci_running"], "rapid_running": st["rapid_running"], "peer_ip": ip,
        "peer_port": -1 if peer is None else peer[1], "sup_ticks": sup.ticks,
        "sup_intervened": sup.intervened, "fault_count": core.fault_count,
    }  # fmt: skip
    for name, value in values.items():
        row[COL[name]] = np.nan if value is None else value
    row[COL["q_meas"]], row[COL["q"]], row[COL["qd"]] = fb.q, last.q, last.qd
    row[COL["qdd"]] = sup.qdd_end
    for name in CORE_COUNTS:
        row[COL[name]] = getattr(core, name)
    for name in EGM_COUNTS:
        row[COL[name]] = getattr(egm.counters, name)
    for kind, n in sup.counts.items():
        row[COL[f"kind_{kind}"]] = n
    return row


def _ipv4(text: str) -> float:
    parts = text.split(".")
    if len(parts) != 4 or not all(p.isdigit() for p in parts):
        return -1.0
    return float(sum(int(p) << (8 * (3 - i)) for i, p in enumerate(parts)))


def ip_text(value: float) -> str:
    """The dotted IPv4 address of :func:`_ipv4`'s number."""
    n = int(value)
    return ".".join(str((n >> s) & 255) for s in (24, 16, 8, 0))
