"""The controller's state as thinkfast-cell shows it: tasks, the kit's variables, the blockers.

Pure: what :meth:`thinkfast.cell.client.Cell.read_state` read over RWS, described for a person
(:func:`format_state`, :func:`start_blockers`) and as JSON (:meth:`CellState.to_json`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

KIT_MODULE = "robots/irb1600/controller/ThinkfastEGM.mod"
KIT_VARIABLES = ("tf_status", "tf_start_request", "tf_stop_request")

_MODES = {"AUTO": "auto", "MANR": "manual reduced speed", "MANF": "manual full speed"}
_MOTORS = {
    "motoron": "on",
    "motoroff": "off",
    "guardstop": "off (guard stop)",
    "emergencystop": "off (emergency stop)",
    "emergencystopreset": "off (emergency stop reset)",
    "sysfail": "off (system failure)",
    "init": "off (initialising)",
}


@dataclasses.dataclass(frozen=True)
class TaskInfo:
    """One RAPID task as the controller lists it."""

    name: str
    type: str
    taskstate: str  # empty | loaded | linked
    excstate: str  # ready | started | stopped | uninitialized
    active: bool
    motion: bool


@dataclasses.dataclass(frozen=True)
class CellState:
    """What ``thinkfast-cell state`` shows.

    ``kit`` maps each of :data:`KIT_VARIABLES` to its value as RWS gives it (``TRUE``,
    ``FALSE``; ``tf_status`` without its quotes), or None when the task has no such symbol.
    """

    url: str
    ctrlstate: str
    opmode: str
    execstate: str
    cycle: str
    speedratio: float  # [%]
    tasks: tuple[TaskInfo, ...]
    kit_task: str
    kit: dict[str, str | None]

    @property
    def motors_on(self) -> bool:
        return self.ctrlstate == "motoron"

    @property
    def auto(self) -> bool:
        return self.opmode == "AUTO"

    @property
    def running(self) -> bool:
        return self.execstate == "running"

    @property
    def status(self) -> str | None:
        """The kit program's ``tf_status``, None without the kit."""
        return self.kit.get("tf_status")

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (booleans for the kit's requests)."""

        def kit_value(name: str, value: str | None) -> Any:
            if value is None or name == "tf_status":
                return value
            return value.upper() == "TRUE"

        return {
            "url": self.url,
            "controller_state": self.ctrlstate,
            "motors_on": self.motors_on,
            "operation_mode": self.opmode,
            "auto": self.auto,
            "rapid_execution": self.execstate,
            "rapid_cycle": self.cycle,
            "speed_ratio_percent": self.speedratio,
            "tasks": [dataclasses.asdict(t) for t in self.tasks],
            "kit": {"task": self.kit_task, **{k: kit_value(k, v) for k, v in self.kit.items()}},
        }


def describe_mode(opmode: str) -> str:
    """``AUTO`` -> ``auto``, ``MANR`` -> ``manual reduced speed``, others lower case."""
    return _MODES.get(opmode, opmode.lower())


def describe_motors(ctrlstate: str) -> str:
    """``motoron`` -> ``on``, ``guardstop`` -> ``off (guard stop)``, others as given."""
    return _MOTORS.get(ctrlstate, ctrlstate)


def start_blockers(state: CellState) -> list[str]:
    """What keeps the kit's program from starting, one phrase each (empty: nothing)."""
    out = []
    if not state.auto:
        out.append(
            f"operation mode is {describe_mode(state.opmode)} ({state.opmode}), needs auto "
            "(key switch on the controller)"
        )
    if not state.motors_on:
        out.append(
            f"motors are {describe_motors(state.ctrlstate)} ({state.ctrlstate}), needs motors "
            "on (motors-on button)"
        )
    if not any(t.name == state.kit_task for t in state.tasks):
        out.append(f"the controller has no RAPID task {state.kit_task}")
    elif state.status is None:
        out.append(f"{state.kit_task} has no tf_status: load {KIT_MODULE} into {state.kit_task}")
    return out


def format_state(state: CellState) -> str:
    """The state as a small aligned table."""
    rows = [
        ("controller", state.url),
        ("motors", f"{describe_motors(state.ctrlstate)} ({state.ctrlstate})"),
        ("mode", f"{describe_mode(state.opmode)} ({state.opmode})"),
        ("RAPID", f"{state.execstate} (cycle {state.cycle})"),
        ("speed ratio", f"{state.speedratio:g} %"),
    ]
    lines = [f"{k:<13}{v}" for k, v in rows]
    header = ("task", "type", "state", "execution", "active", "motion")
    table = [header] + [
        (
            t.name,
            t.type,
            t.taskstate,
            t.excstate,
            "on" if t.active else "off",
            str(t.motion).lower(),
        )
        for t in state.tasks
    ]
    widths = [max(len(r[i]) for r in table) for i in range(len(header))]
    lines.append("")
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in table]
    lines.append("")
    lines.append(f"kit ({state.kit_task})")
    for name in KIT_VARIABLES:
        value = state.kit.get(name)
        shown = "(not found)" if value is None else (value or '""')
        lines.append(f"  {name:<18}{shown}")
    return "\n".join(lines)
