"""The executor's modes and stage keys: the names the status, the record and the views share.

A throw episode runs idle -> tracking -> executing -> returning -> idle (fault: latched until
restarted); a mode's value is the status ``state`` and the setpoints' ``mode``. The stage keys
name the hedge stage's part of the status and of the record's ``stage`` events.
"""

from __future__ import annotations

import enum


class Mode(enum.StrEnum):
    """State of the executor (its value is the status ``state`` and the setpoints' ``mode``)."""

    IDLE = "idle"
    TRACKING = "tracking"
    EXECUTING = "executing"
    RETURNING = "returning"
    FAULT = "fault"


IDLE, TRACKING, EXECUTING, RETURNING, FAULT = Mode  # the names the rest of the package uses
STAGE_KEYS = ("stage", "hedge_end", "hedges", "throw_end")  # the status's and record's stage
