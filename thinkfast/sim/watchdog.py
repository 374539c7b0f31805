"""The simulators' watch on a daemon they throw at: is it there, is it still there.

:class:`Watchdog` follows the EGM replies the simulated controller gets and the status messages
the daemon publishes on zenoh. Before the throws, :meth:`Watchdog.wait_ready` waits for
conditions, not for a fixed time: a second of EGM exchange, a status heard (the daemon's loop
runs and its messages reach this session) and a subscriber of the detections reachable (this
session's messages reach the daemon), so a slow host only waits longer. During the throws,
:meth:`Watchdog.check` raises :class:`DaemonGone` once either has been silent for ``silence``.
"""

from __future__ import annotations

import json
import time

from thinkfast.contract import keys
from thinkfast.control.modes import IDLE
from thinkfast.errors import ThinkfastError

SILENCE = 3.0  # s without an EGM reply or a status: the daemon is gone (status comes at 20 Hz)
READY_REPLIES = 250  # EGM replies before the throws: a second at 250 Hz
# EGM replies are counted late or not (the runner's ``stats.answered``): on a loaded host most
# come after their 4 ms cycle, and a daemon that answers late is there all the same.


class DaemonGone(ThinkfastError):
    """The daemon stopped answering EGM or publishing its status while throws were running."""


class Watchdog:
    """Notices a daemon that died: no EGM reply to the simulated controller, or no status on
    zenoh, for ``silence`` seconds (checked while the thrower waits).

    Args:
        runner: the simulated controller's runner (``stats.answered``).
        session: an open zenoh session reaching the daemon.
        prefix: the daemon's key prefix.
        egm: (host, port) of the daemon's EGM socket, for the messages.
        silence: seconds of silence that mean the daemon is gone.
    """

    def __init__(self, runner, session, prefix: str, egm, silence: float):
        self.runner, self.egm, self.silence = runner, egm, silence
        now = time.monotonic()
        self._replies, self._reply_at, self.status_at = 0, now, now
        self.heard = False  # a status arrived
        self._last_status = b""  # the newest status payload, read in the thrower's thread
        self._sub = session.declare_subscriber(keys.status(prefix), self._on_status)

    def _on_status(self, sample) -> None:
        self.status_at = time.monotonic()  # a time and a reference: nothing else in zenoh's
        self._last_status = sample.payload.to_bytes()  # thread
        self.heard = True

    def idle(self) -> bool:
        """The daemon's newest status says ``idle`` (at home, ready for a throw)."""
        try:
            return json.loads(self._last_status).get("state") == IDLE
        except ValueError:
            return False

    def wait_ready(self, matching, timeout: float, total: int = 0) -> None:
        """Wait until the daemon answered ``READY_REPLIES`` EGM packets, a status of it arrived
        and ``matching()`` is true (a subscriber of the detections is reachable), polling every
        50 ms. Once it answered and was heard, a silence as in :meth:`check` ends the wait.

        Raises:
            DaemonGone: not ready within ``timeout`` [s], naming what is missing; or gone
                (:meth:`check`, ``total``: the throws to come).
        """
        deadline = time.monotonic() + timeout
        while True:
            if self.heard and self.runner.stats.answered > 0:
                self.check(0, total)
            missing = [
                what
                for what, ok in (
                    (f"{READY_REPLIES} EGM replies", self.runner.stats.answered >= READY_REPLIES),
                    ("status heard", self.heard),
                    ("subscriber of the detections", matching()),
                )
                if not ok
            ]
            if not missing:
                return
            if time.monotonic() > deadline:
                raise DaemonGone(
                    f"the daemon at EGM {self.egm[0]}:{self.egm[1]} is not ready after "
                    f"{timeout:g} s: no {', no '.join(missing)}"
                )
            time.sleep(0.05)

    def check(self, done: int, total: int) -> None:
        """Raise :class:`DaemonGone` (naming what went silent) when the daemon is gone."""
        now = time.monotonic()
        replies = self.runner.stats.answered
        if replies != self._replies:
            self._replies, self._reply_at = replies, now
        quiet = []
        if now - self._reply_at > self.silence:
            quiet.append(f"no EGM reply for {now - self._reply_at:.1f} s")
        if now - self.status_at > self.silence:
            quiet.append(f"no status for {now - self.status_at:.1f} s")
        if quiet:
            raise DaemonGone(
                f"the daemon at EGM {self.egm[0]}:{self.egm[1]} stopped ({', '.join(quiet)}) "
                f"after {done} of {total} throws"
            )

    def sleep_until(self, t_wall: float, done: int, total: int, until_idle: bool = False) -> None:
        """Sleep until wall time ``t_wall`` [s], checking the daemon every 0.1 s; with
        ``until_idle``, no longer than until its status says ``idle``."""
        while True:
            self.check(done, total)
            left = t_wall - time.time()
            if left <= 0.0 or (until_idle and self.idle()):
                return
            time.sleep(min(left, 0.02 if until_idle else 0.1))
