"""zenoh sessions: configuration from the command line, opening with one-line errors, draining a
subscriber's queue, and a warning when a session hears no one. Every program of the project
opens its sessions here (daemon, detector, simulator, tools and tests).

Keyword arguments only for endpoints: ``connect`` and ``listen`` are easy to swap.
"""

from __future__ import annotations

import itertools
import json
import logging
import socket
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import zenoh

from thinkfast.contract.zenoh_auth import SessionSecurity, security_of
from thinkfast.errors import ConfigError

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
    return [sample.payload.to_bytes() for sample in drain_samples(sub, limit)]


def drain_samples(sub, limit: int) -> list:
    """Samples (payload and attachment) queued in the channel of ``sub`` (at most ``limit``),
    never blocking."""
    out = []
    for _ in range(limit):
        try:
            sample = sub.try_recv()
        except Exception:  # channel closed while shutting down
            break
        if sample is None:
            break
        out.append(sample)
    return out


def attributed_put(publisher: zenoh.Publisher) -> Callable[..., None]:
    """``publisher.put`` with the sample's source attached (the publisher's session and entity
    id, and a sequence number): a daemon on a secured session admits a detection only from the
    link of its camera's node, found by that source (docs/SECURITY.md)."""
    entity, serial = publisher.id, itertools.count()

    def put(payload, **kwargs) -> None:
        publisher.put(payload, source_info=zenoh.SourceInfo(entity, next(serial)), **kwargs)

    return put


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
    *,
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    config_file: str | Path | None = None,
    multicast: bool | None = None,
) -> zenoh.Config:
    """A zenoh configuration: peer mode (or the JSON5 file's), plus endpoints from the CLI.

    ``multicast=False`` turns multicast scouting off (loopback tests and tools: no stray peers);
    None leaves zenoh's default (or the file's).

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
        if multicast is not None:
            conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    except Exception as exc:
        raise ConfigError(
            "--zenoh-connect/--zenoh-listen", None, f"rejected by zenoh ({exc})"
        ) from None
    return conf


_SECURITY_KEYS = ("mode", "listen", "connect", "scouting", "transport/link/tls", "access_control")


def config_dict(conf: zenoh.Config) -> dict:
    """The parts of ``conf`` that say who can reach the session, as plain data (nested as in
    zenoh's schema; unset values are None)."""
    out: dict = {}
    for key in _SECURITY_KEYS:
        try:
            value = json.loads(conf.get_json(key))
        except Exception:  # not in this zenoh's schema
            value = None
        node = out
        *path, last = key.split("/")
        for part in path:
            node = node.setdefault(part, {})
        node[last] = value
    return out


def session_security(conf: zenoh.Config) -> SessionSecurity:
    """What ``conf`` exposes and what guards it
    (:func:`~thinkfast.contract.zenoh_auth.security_of`)."""
    return security_of(config_dict(conf))


def open_peer(
    *,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | Path | None = None,
) -> zenoh.Session:
    """A peer session on explicit endpoints with multicast scouting off (tests and tools);
    ``config_file``: a zenoh JSON5 configuration under them (e.g. a secured cell node's, whose
    TLS and access control it keeps; the endpoints given replace the file's)."""
    return open_session(
        session_config(listen=listen, connect=connect, config_file=config_file, multicast=False)
    )


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago on ``host`` (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def loopback_endpoint() -> str:
    """A zenoh endpoint ``tcp/127.0.0.1:<free port>`` to listen on."""
    return f"tcp/127.0.0.1:{free_tcp_port()}"
