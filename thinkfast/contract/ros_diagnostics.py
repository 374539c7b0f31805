"""The daemon's status as ``diagnostic_msgs/msg/DiagnosticArray`` (docs/ROS2.md).

One DiagnosticStatus named ``thinkfast: daemon`` per status: its level says whether the daemon
is in fault, braking or without a controller, its values are the status's keys. The CDR codec
is :mod:`thinkfast.contract.ros`'s.
"""

from __future__ import annotations

import json
from typing import Any, NamedTuple

from thinkfast.contract.ros import DIAGNOSTIC_ARRAY, decode_cdr, header, seconds, typestore

# DiagnosticStatus levels (diagnostic_msgs/msg/DiagnosticStatus: OK 0, WARN 1, ERROR 2, STALE 3)
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR, LEVEL_STALE = 0, 1, 2, 3
DIAG_NAME = "thinkfast: daemon"


def hardware_id(status: dict) -> str:
    """The DiagnosticStatus ``hardware_id`` of a daemon status: the name of the robot it runs
    (its ``robot.name``; empty in a status that names none)."""
    robot = status.get("robot")
    name = robot.get("name") if isinstance(robot, dict) else None
    return name if isinstance(name, str) else ""


def status_level(status: dict) -> tuple[int, str]:
    """Diagnostic level and message of a daemon status: ERROR in ``fault``, WARN while braking,
    while the controller is not talking, or while it does not follow (standby); else OK. The
    message is the state, and why when it is not OK."""
    state = str(status.get("state"))
    if status.get("exiting"):
        return LEVEL_STALE, f"{state}: exiting"
    if state == "fault":
        return LEVEL_ERROR, f"fault: {status.get('brake_reason')}"
    if status.get("braking"):
        return LEVEL_WARN, f"{state}: braking ({status.get('brake_reason')})"
    if not status.get("egm_connected", True):
        return LEVEL_WARN, f"{state}: no EGM controller"
    if (status.get("controller") or {}).get("standby"):
        return LEVEL_WARN, f"{state}: controller standby (motors, EGM motion or RAPID stopped)"
    return LEVEL_OK, state


def _value_text(v: Any) -> str:
    return v if isinstance(v, str) else json.dumps(v, separators=(",", ":"))


def encode_diagnostics(status: dict) -> bytes:
    """``diagnostic_msgs/msg/DiagnosticArray`` in CDR of one daemon status (stamp from
    ``status['stamp']``): one DiagnosticStatus named ``thinkfast: daemon`` whose level and
    message come from :func:`status_level`, whose ``hardware_id`` is the robot's name
    (:func:`hardware_id`) and whose values are the status's keys (strings as they are,
    everything else as compact JSON)."""
    ts = typestore()
    T = ts.types
    level, message = status_level(status)
    values = [
        T["diagnostic_msgs/msg/KeyValue"](key=str(k), value=_value_text(v))
        for k, v in status.items()
    ]
    st = T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level,
        name=DIAG_NAME,
        message=message,
        hardware_id=hardware_id(status),
        values=values,
    )
    msg = T[DIAGNOSTIC_ARRAY](header=header(float(status["stamp"]), ""), status=[st])
    return bytes(ts.serialize_cdr(msg, DIAGNOSTIC_ARRAY))


class DiagnosticMsg(NamedTuple):
    """One decoded DiagnosticStatus of a DiagnosticArray (with the array's stamp [s])."""

    stamp: float
    level: int
    name: str
    message: str
    hardware_id: str
    values: dict[str, str]


def decode_diagnostics(cdr: bytes) -> list[DiagnosticMsg]:
    """Read a ``diagnostic_msgs/msg/DiagnosticArray`` (raises :class:`RosDecodeError`)."""
    m = decode_cdr(cdr, DIAGNOSTIC_ARRAY)
    stamp = seconds(m.header.stamp)
    return [
        DiagnosticMsg(
            stamp, int(s.level), s.name, s.message, s.hardware_id,
            {kv.key: kv.value for kv in s.values},
        )
        for s in m.status
    ]  # fmt: skip
