"""zenoh edge of the daemon: session from the command line, detections in, JSON out.

Detections are queued by zenoh's own thread into a bounded FIFO and drained by the control loop
with ``try_recv`` (nothing runs inside a zenoh callback). Setpoints and status go out as UTF-8
JSON on ``<prefix>/setpoints`` and ``<prefix>/status`` (docs/INTERFACES.md).
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Sequence
from pathlib import Path

import zenoh

from thinkfast.errors import ConfigError

QUEUE = 4096  # detections buffered between two drains (80 s at 50 Hz)
ALONE_AFTER = 3.0  # s: a session with no peer and no router this long after opening is warned
log = logging.getLogger("thinkfast.zenoh")


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """A zenoh session; a failure becomes a one-line :class:`ConfigError`."""
    try:
        return zenoh.open(conf)
    except Exception as exc:
        raise ConfigError("zenoh", None, f"cannot open a session ({exc})") from None


def drain(sub, limit: int) -> list[bytes]:
    """Payloads queued in the channel of subscriber ``sub`` (at most ``limit``), never blocking."""
    out = []
    for _ in range(limit):
        try:
            sample = sub.try_recv()
        except Exception:  # channel closed while shutting down
            break
        if sample is None:
            break
        out.append(sample.payload.to_bytes())
    return out


def neighbours(session: zenoh.Session) -> int:
    """zenoh peers plus routers ``session`` is connected to now (0 when it cannot tell)."""
    try:
        info = session.info
        return len(list(info.peers_zid())) + len(list(info.routers_zid()))
    except Exception:  # closed meanwhile
        return 0


def warn_if_alone(session: zenoh.Session, what: str, after: float = ALONE_AFTER) -> threading.Timer:
    """Log one warning when ``session`` is connected to no zenoh peer or router ``after`` seconds
    from now: nothing it publishes reaches anyone and nothing arrives (a wrong or missing
    ``--zenoh-connect``, a firewall, scouting off). Runs on a timer thread; cancel it on close.

    Args:
        session: an open session.
        what: what goes unheard, for the message (e.g. ``thinkfast/status``).
        after: grace period for discovery and connection [s].
    """

    def check() -> None:
        if neighbours(session) == 0:
            log.warning(
                "no zenoh peer or router connected %.0f s after start: %s reach no one "
                "(check --zenoh-connect / --zenoh-listen / --zenoh-config)",
                after,
                what,
            )

    timer = threading.Timer(after, check)
    timer.daemon = True
    timer.start()
    return timer


def close_session(session: zenoh.Session) -> None:
    """Close ``session``; a session already gone is not an error at shutdown."""
    try:
        session.close()
    except Exception:
        pass


def session_config(
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    config_file: str | Path | None = None,
) -> zenoh.Config:
    """A zenoh configuration: peer mode (or the JSON5 file's), plus endpoints from the CLI.

    Raises:
        ConfigError: the file cannot be read or an endpoint is rejected by zenoh.
    """
    try:
        conf = zenoh.Config.from_file(str(config_file)) if config_file else zenoh.Config()
    except Exception as exc:  # zenoh raises its own ZError
        raise ConfigError(str(config_file), None, f"invalid zenoh configuration ({exc})") from None
    try:
        if not config_file:
            conf.insert_json5("mode", '"peer"')
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    except Exception as exc:
        raise ConfigError(
            "--zenoh-connect/--zenoh-listen", None, f"rejected by zenoh ({exc})"
        ) from None
    return conf


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
            f"{prefix}/detections", zenoh.handlers.FifoChannel(QUEUE)
        )
        self.pub_setpoints = self.session.declare_publisher(f"{prefix}/setpoints")
        self.pub_status = self.session.declare_publisher(f"{prefix}/status")
        self.prefix = prefix
        self._described = {
            "mode": _conf_json(conf, "mode"),
            "connect": _conf_json(conf, "connect/endpoints"),
            "listen": _conf_json(conf, "listen/endpoints"),
        }

        self.alone = warn_if_alone(
            self.session, f"{prefix}/status and {prefix}/setpoints (and no detections arrive)"
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

    def publish_setpoint(self, stamp: float, q, qd, mode: str) -> None:
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
