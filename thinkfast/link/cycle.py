"""Where the daemon's loop stands in the EGM cycle: when it may sleep, spin, prepare the next
reply and do other work. Pure: times in, decisions out (the daemon reads the clock).

The controller sends an ``EgmRobot`` every ``dt`` (4 ms), so the next one is due ``dt`` after the
last. The *window* opens ``ahead`` before that and closes ``SPIN_LATE`` after it:

* at its opening the daemon prepares the next reply (setpoint and supervisor filter ahead), so
  that little work is left when the packet comes;
* with ``spin_ahead`` the loop spins on the socket inside the window instead of sleeping: on a
  virtual machine Python runs several times slower right after a sleep. ``spin_ahead >= dt``
  (busy polling) spins all the time and costs a whole core;
* other work (detections, status, garbage collection) ends before the window opens, and at least
  ``WORK_GUARD`` before the packet is due; a controller silent for ``SILENT`` leaves all the time
  free.

Sleeps are whole milliseconds (``poll``): the loop naps 1 ms at a time only while a whole
millisecond remains before the window opens, and spins from there on, so it starts spinning up to
1 ms early (late only by the OS's wake-up latency).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

WORK_GUARD = 0.0005  # s: work between replies ends at least this long before the next is due
SILENT = 0.02  # s without an EgmRobot: the controller is not cycling, work at any time
SPIN_LATE = 0.002  # s after the next EgmRobot was due: the window closes (sleep until it comes)
PREPARE_AHEAD = 0.001  # s: the window's opening without spinning (or when always spinning)


@dataclass(frozen=True)
class Cycle:
    """Timing rules of one EGM cycle (see the module doc).

    Args:
        dt: controller cycle [s] (0.004).
        spin_ahead: spin from this long before the next EgmRobot is due [s]; 0 never spins,
            ``>= dt`` always spins.
    """

    dt: float
    spin_ahead: float = 0.0

    @property
    def busy(self) -> bool:
        """The loop never sleeps."""
        return self.spin_ahead >= self.dt

    @property
    def ahead(self) -> float:
        """The window opens this long [s] before the next EgmRobot is due."""
        return self.spin_ahead if 0.0 < self.spin_ahead < self.dt else PREPARE_AHEAD

    def in_window(self, since: float) -> bool:
        """``since`` [s] after the last EgmRobot, the next one is due within ``ahead`` (or is
        late by at most ``SPIN_LATE``)."""
        return self.dt - self.ahead <= since <= self.dt + SPIN_LATE

    def wait_ms(self, since: float) -> int:
        """How long the loop may sleep in ``poll`` [ms], ``since`` [s] after the last EgmRobot:
        0 to spin, at most 1 so that queued work is looked at every millisecond."""
        if self.spin_ahead <= 0.0:
            return 1
        if self.busy:
            return 0
        if since > self.dt + SPIN_LATE:  # late or silent controller: nap until it comes
            return 1
        return 1 if self.dt - self.spin_ahead - since >= 0.001 else 0

    def time_left(self, since: float) -> float:
        """Seconds of other work that still end before the window opens (and ``WORK_GUARD``
        before the next EgmRobot is due), ``since`` [s] after the last one; inf when the
        controller is silent."""
        if since > SILENT:
            return math.inf
        return self.dt - max(WORK_GUARD, self.ahead) - since
