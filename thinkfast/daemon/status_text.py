"""The daemon's status message and start-up summary, read off its parts.

:func:`status_message` is what ``thinkfast-run`` publishes at ``status_rate`` on
``<prefix>/status`` (docs/INTERFACES.md "Status"; read back by ``thinkfast-run status``,
:mod:`thinkfast.daemon.status_view`); :func:`summary` is logged (and recorded) at start-up;
:func:`episode_text` ends a throw's ``throw_end`` event (:func:`episode_end`: or an
``episode_end`` for an episode never confirmed). Plain JSON-able data; nothing here
changes the daemon.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from thinkfast.control.core import FAULT_REASONS
from thinkfast.control.modes import FAULT
from thinkfast.control.outcome import CoreState

if TYPE_CHECKING:
    from thinkfast.daemon.daemon_parts import DaemonParts


def status_message(d: DaemonParts, now: float) -> dict:
    """The status message (docs/INTERFACES.md: at least stamp and state)."""
    ctl, sup = d.control, d.supervisor
    st = ctl.state()
    fault = ctl.latched or (sup.braking and sup.brake_reason in FAULT_REASONS)
    return {
        "stamp": now,
        "state": FAULT if fault or d.home.held(ctl) else st.mode,
        "planner": d.planner,
        "throws": st.throws,
        "node": st.node,
        "value": st.value,
        "decision_ms": round(d.decision_ms, 3),
        "stage": st.stage,
        "detections": d.intake.as_dict(),
        "zenoh": d.zio.as_dict(),
        "cameras": st.cameras,
        **({} if d.view is None else {"view": d.view.as_dict()}),
        "egm": {**vars(d.link.counters), "repeated": ctl.repeats, "resyncs": ctl.resyncs},
        "loop": {  # the reply loop's own counters (docs/ARCHITECTURE.md, The EGM path)
            "missed_cycles": ctl.held,
            "catch_ups": ctl.catch_ups,
            "late_replies": d.link.counters.behind,
        },
        "egm_peer": peer_text(d.link.peer),
        "egm_foreign": dict(d.link.foreign_sources),
        "egm_connected": d.connected(now),
        "safety": {k: v for k, v in sup.counts.items() if v},
        "interventions": {
            "ticks": sup.ticks,
            "intervened": sup.intervened,
            "last_throw": d.last_throw,
        },
        "faults": {"count": ctl.fault_count, "recent": len(ctl.faults), "latched": ctl.latched},
        "braking": sup.braking,
        "brake_reason": sup.brake_reason,
        "planner_errors": d.planner_errors,
        "recorder": d.recorder.status(),
        "egm_timing": None if d.link.timing is None else d.link.timing.summary(),
        "controller": {
            **(d.controller_state or {}),
            "standby": ctl.standby,
            "standby_replies": ctl.standby_replies,
        },
        "away_from_home": st.away,
        "way_home": None if d.home.way_home is None else way_text(d.home.way_home.result),
        "shadow": None if not d.modes.shadow else planned_text(d.planned),
        "speed_scale": d.modes.speed_scale,
        **cell_text(d),
    }


def cell_text(d: DaemonParts) -> dict:
    """The cell the daemon runs (in the status and the start-up summary): its robot (name,
    robot.toml, its sha256), the tree's fingerprint and the plane's distance x [m]."""
    robot = d.robot
    return {
        "robot": {
            "name": robot.name,
            "robot_toml": str(robot.toml_path),
            "robot_toml_sha256": robot.toml_sha256[:16],
        },
        "tree_fingerprint": d.tree_fingerprint[:16],
        "plane_x": d.plane_x,
    }


def summary(d: DaemonParts) -> dict:
    """What the daemon runs with (logged at start-up)."""
    cfg, robot, meta = d.cfg, d.robot, d.tree_meta
    return {
        "robot": cell_text(d)["robot"],
        "tree_fingerprint": d.tree_fingerprint[:16],
        "tree_config_sha256": str(meta.get("config_sha256", ""))[:16],
        "tree_urdf_sha256": str(meta.get("urdf_sha256", ""))[:16],
        "planner": d.planner,
        "plane_x": d.plane_x,
        "camera": {"xyz": list(cfg.camera.xyz), "rpy": list(cfg.camera.rpy)},
        "egm": peer_text(d.link.address),
        "zenoh": d.zio.describe(),
        "limits": {
            "v_max": np.round(robot.v_max, 3).tolist(),
            "a_max": np.round(robot.a_max, 2).tolist(),
            "j_max": np.round(robot.j_max, 1).tolist(),
            "position_margin": cfg.safety.position_margin,
        },
        "controller_lag": cfg.execution.controller_lag,
        "shadow": d.modes.shadow,
        "go_home": d.modes.go_home,
        "speed_scale": d.modes.speed_scale,
        "record": str(d.recorder.path) if d.recorder.enabled else None,
    }


def episode_text(st: CoreState) -> dict:
    """What the daemon knows of the episode that just ended (``st.ended``; whether it was
    blocked, it cannot): ``throws`` confirmed so far, whether this one was ``confirmed``, its
    ``hedges`` (and why the last ended), and for a throw that moved the arm its figures. An
    episode never confirmed (a ball tracked, perhaps hedged on) has figures of its own, never
    the previous throw's."""
    ep = st.ended
    out: dict = {"throws": st.throws, "executed": False}
    if ep is None:
        return out
    out["confirmed"] = not math.isnan(ep.t_confirmed)
    out["hedges"] = ep.hedges
    if ep.hedges:
        out["hedge_end"] = ep.hedge_end
    if math.isnan(ep.t_start):
        return out
    value = None if math.isnan(ep.chosen_value) else round(ep.chosen_value, 3)
    return {
        **out,
        "executed": True,
        "start_after_confirm": round(ep.t_start - ep.t_confirmed, 4),
        "cross_after_start": None if math.isnan(ep.t_cross) else round(ep.t_cross - ep.t_start, 3),
        "value": value,
        "decisions": ep.decisions,
        "end": ep.end,
    }


def episode_end(st: CoreState) -> tuple[str, dict]:
    """The event that closes the episode that just ended and its detail (:func:`episode_text`):
    ``throw_end`` for a confirmed throw, ``episode_end`` for one never confirmed."""
    detail = episode_text(st)
    return ("throw_end" if detail.get("confirmed") else "episode_end"), detail


def way_text(result) -> str:
    if result is None:
        return "checking"
    return "clear" if result.clear else f"blocked: {result.detail}"


def planned_text(planned) -> dict | None:
    if planned is None:
        return None
    q, qd, mode = planned
    return {"q": np.round(q, 6).tolist(), "qd": np.round(qd, 6).tolist(), "mode": mode}


def peer_text(peer) -> str | None:
    return None if peer is None else f"{peer[0]}:{peer[1]}"
