"""What the control core knows of a controller: one feedback record in, a setpoint out.

A controller link (:class:`ControllerLink`) owns the wire: it receives the controller's feedback,
turns it into a :class:`Feedback` (joints [rad], the controller's clock [ms] and cycle count, its
readiness) and sends back the setpoint the core answers with. The core never sees the wire's
messages, so another controller (another vendor's streaming interface, a simulator, a replay)
plugs in as a link of its own (:mod:`thinkfast.link`: the registry; EGM is the real one). Pure:
no sockets here, only the shapes both sides agree on.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np


class Feedback(NamedTuple):
    """One feedback from the controller, in the core's terms.

    Attributes:
        t_ms: the controller's clock [ms] (wraps at 2**32), None when it reports none.
        q: measured joint angles [rad], shape (n_joints,).
        cycle: the controller's cycle count (wraps at 2**32), None when it reports none (the
            cycles are then counted by ``t_ms``).
        ready: the controller follows references (for EGM: motors on, EGM motion running,
            RAPID not stopped); otherwise the core commands the measured position at rest.
        state: the link's own readiness parts, ``((name, value), ...)``, for the status and the
            record (EGM: ``motors_on``, ``mci_running``, ``rapid_running``).
    """

    t_ms: int | None
    q: np.ndarray
    cycle: int | None = None
    ready: bool = True
    state: tuple = ()


# The driver's answer to one feedback: (q [rad], qd [rad/s]) to send, or None to leave it
# unanswered; ``before`` is the feedback just before it when that one went unanswered.
ReplyFn = Callable[[Feedback, "Feedback | None"], "tuple[np.ndarray, np.ndarray] | None"]


class LinkCounters(Protocol):
    """A link's counters (the status's ``egm`` object): ``vars()`` of it is JSON-able."""

    behind: int  # replies that reached the controller after its next cycle began


class ControllerLink(Protocol):
    """One controller on one wire (module doc): the daemon's loop waits on :meth:`fileno` and
    calls :meth:`poll`, which answers the newest feedback through the link's reply function.

    Attributes:
        address: where the link listens (for the log), ``(host, port)`` or a name.
        peer: the controller being served (its address), None before the first feedback.
        behind: the feedback being answered arrived before the last reply left (the reply
            reached the controller a cycle late).
        counters: :class:`LinkCounters`. foreign_sources: ``{source: messages}`` refused.
        timing: reply times (``summary()``: JSON-able), or None.
    """

    address: object
    peer: object
    behind: bool
    counters: LinkCounters
    foreign_sources: dict
    timing: object

    def fileno(self) -> int:
        """A descriptor that is readable when feedback waits."""
        ...

    def poll(self) -> int:
        """Take what waits and answer the newest feedback; returns the replies sent (0 or 1)."""
        ...

    def close(self) -> None:
        """Release the wire."""
        ...
