"""The EGM link: ABB's Externally Guided Motion as a controller link.

:class:`~thinkfast.link.egm_server.EgmServer` owns the UDP socket and EGM's bookkeeping (one
peer, the newest packet answered, counters, reply times); this module turns each ``EgmRobot``
it decodes into the core's neutral :class:`~thinkfast.control.link.Feedback` (EGM's header stamp
and sequence number, its motor, MCI and RAPID states), so nothing past the link reads EGM.
"""

from __future__ import annotations

from thinkfast.contract.egm import RobotFeedback
from thinkfast.control.link import Feedback, ReplyFn
from thinkfast.link.egm_server import EgmServer
from thinkfast.link.registry import LinkSpec


def egm_feedback(fb: RobotFeedback) -> Feedback:
    """One decoded ``EgmRobot`` as the core's feedback record."""
    state = (
        ("motors_on", fb.motors_on),
        ("mci_running", fb.mci_running),
        ("rapid_running", fb.rapid_running),
    )
    return Feedback(fb.tm_ms, fb.q_rad, fb.seqno, fb.ready, state)


def open_egm(spec: LinkSpec, reply: ReplyFn) -> EgmServer:
    """The EGM server on ``spec.bind`` answering with ``reply`` on neutral feedback, reply
    times kept (a reply later than ``spec.dt`` is late)."""

    def on_robot(fb: RobotFeedback, before: RobotFeedback | None = None):
        return reply(egm_feedback(fb), None if before is None else egm_feedback(before))

    egm = EgmServer(spec.bind, on_robot, spec.controller, timing=True, handover=spec.handover)
    egm.timing.late_after = spec.dt
    return egm
