"""The status of a reply process whose planner process died (``--reply-process``).

The planner process publishes the daemon's status; when it dies, the reply process, still
answering the controller with the arm braked and held, publishes a status of its own so that the
cell never sees silence: ``state`` ``fault`` with ``fault`` ``planner_lost``, what it commands
and its EGM counters, once a second on ``<prefix>/status`` (docs/INTERFACES.md: stamp and state
at least). It runs in a thread with its own zenoh session, opened only then: the arm is held
braked, and the reply loop never waits for it (it reads plain attributes).
"""

from __future__ import annotations

import json
import sys
import threading
import time

import numpy as np


def preload() -> None:
    """Import zenoh now, at the reply process's start: imported by the status thread once the
    planner is lost, the loading of its extension holds the interpreter lock, and with it the
    reply loop, for a few cycles (docs/BENCHMARKS.md) just as the arm starts to brake. A
    failure is left for the thread to report."""
    try:
        import zenoh  # noqa: F401

        from thinkfast.contract import keys  # noqa: F401
    except Exception:
        pass


def start(zenoh_json: str, prefix: str, loop) -> threading.Thread:
    """Publish ``loop``'s status (a :class:`~thinkfast.reply.process.ReplyLoop`) from a
    daemon thread, on a session of the zenoh configuration ``zenoh_json`` (JSON5)."""
    th = threading.Thread(target=_run, args=(zenoh_json, prefix, loop), daemon=True)
    th.start()
    return th


def status(loop, now: float) -> dict:
    """The status message of a reply loop without its planner."""
    core, sup, egm = loop.core, loop.core.sup, loop.link
    return {
        "stamp": now,
        "state": "fault",
        "fault": "planner_lost",
        "planner_lost": {"pid": loop.parent},
        "braking": sup.braking,
        "brake_reason": sup.brake_reason,
        "q": np.round(np.asarray(sup.q), 6).tolist(),
        "qd": np.round(np.asarray(sup.qd), 6).tolist(),
        "egm": dict(vars(egm.counters)) if egm is not None else {},
        "loop": {"missed_cycles": core.held, "catch_ups": core.catch_ups},
    }


def _run(zenoh_json: str, prefix: str, loop) -> None:
    try:
        import zenoh

        from thinkfast.contract import keys
    except Exception as exc:  # the log line on stderr still says what happened
        print(f"thinkfast reply process: no status on zenoh ({exc})", file=sys.stderr)
        return
    pub, said = None, None
    while pub is None:  # the dead planner's endpoint may not be free at once: try again
        try:
            session = zenoh.open(zenoh.Config.from_json5(zenoh_json))
            pub = session.declare_publisher(keys.status(prefix))
        except Exception as exc:
            if str(exc) != said:
                print(f"thinkfast reply process: no status on zenoh yet ({exc}); trying again "
                      "every second", file=sys.stderr)  # fmt: skip
                said = str(exc)
            time.sleep(1.0)
    if said is not None:
        print("thinkfast reply process: status on zenoh again", file=sys.stderr)
    while True:
        pub.put(json.dumps(status(loop, time.time())).encode())
        time.sleep(1.0)
