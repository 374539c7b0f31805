"""zenoh edge of the daemon: session from the command line, detections in, JSON out.

Detections are queued by zenoh's own thread into a bounded FIFO and drained by the control loop
with ``try_recv`` (nothing runs inside a zenoh callback). Setpoints and status go out as UTF-8
JSON on ``<prefix>/setpoints`` and ``<prefix>/status`` (docs/INTERFACES.md).
"""

from __future__ import annotations

import json

import zenoh

from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import close_session, drain, open_session, warn_if_alone

QUEUE = 4096  # detections buffered between two drains (80 s at 50 Hz)


def _conf_json(conf: zenoh.Config, key: str):
    """A configuration value as plain data, or None when zenoh has none for ``key``."""
    try:
        return json.loads(conf.get_json(key))
    except Exception:
        return None


class ZenohIO:
    """Subscriber and publishers of the daemon on one session.

    Args:
        conf: zenoh configuration.
        prefix: key prefix (default ``thinkfast``).
    """

    def __init__(self, conf: zenoh.Config, prefix: str):
        self.session = open_session(conf)
        self.sub = self.session.declare_subscriber(
            keys.detections(prefix), zenoh.handlers.FifoChannel(QUEUE)
        )
        self.pub_setpoints = self.session.declare_publisher(keys.setpoints(prefix))
        self.pub_status = self.session.declare_publisher(keys.status(prefix))
        self.prefix = prefix
        self._described = {
            "mode": _conf_json(conf, "mode"),
            "connect": _conf_json(conf, "connect/endpoints"),
            "listen": _conf_json(conf, "listen/endpoints"),
        }

        self.alone = warn_if_alone(
            self.session,
            f"{keys.status(prefix)} and {keys.setpoints(prefix)} (and no detections arrive)",
        )

    def describe(self) -> dict:
        """Mode, endpoints, key prefix and session id (for the start-up log line)."""
        try:
            zid = str(self.session.info.zid())
        except Exception:
            zid = None
        return {**self._described, "prefix": self.prefix, "zid": zid}

    def drain(self, limit: int = 256) -> list[bytes]:
        """Payloads received since the last call (at most ``limit``)."""
        return drain(self.sub, limit)

    def publish_setpoint(self, stamp: float, q, qd, mode: str, q_meas=None) -> None:
        """Mirror one setpoint (``q_meas``, the feedback it answers, is for the ROS edge)."""
        msg = {
            "stamp": stamp,
            "q": [float(x) for x in q],
            "qd": [float(x) for x in qd],
            "mode": mode,
        }
        self.pub_setpoints.put(json.dumps(msg).encode())

    def publish_status(self, status: dict) -> None:
        self.pub_status.put(json.dumps(status).encode())

    def close(self) -> None:
        self.alone.cancel()
        close_session(self.session)
