"""zenoh edge of the daemon: session from the command line, detections in, JSON out.

Detections are queued by zenoh's own thread into a bounded FIFO and drained by the control loop
with ``try_recv`` (nothing runs inside a zenoh callback). Setpoints and status go out as UTF-8
JSON on ``<prefix>/setpoints`` and ``<prefix>/status`` (docs/INTERFACES.md).

On a secured session (mutual TLS, docs/SECURITY.md) a detection moves the arm only when it came
over the link of its own camera's node: :class:`SenderGate` knows each link's certificate name
from zenoh's link events and reads the sample's source (the publisher's session id, which the
project's camera nodes attach); anything else is counted and dropped before the intake.
"""

from __future__ import annotations

import json
import logging
import threading

import zenoh

from thinkfast.contract import keys
from thinkfast.contract.zenoh_auth import camera_of, role_of
from thinkfast.contract.zenoh_session import (
    close_session,
    drain_samples,
    open_session,
    session_security,
    warn_if_alone,
)

QUEUE = 4096  # detections buffered between two drains (80 s at 50 Hz)
INSECURE_WARN_EVERY = 60.0  # s between two warnings of a session opened with --insecure-zenoh
REJECTS = ("unattributed", "unlinked", "not_a_camera", "wrong_camera")
log = logging.getLogger("thinkfast.zenoh")


class SenderGate:
    """Admits a detection sample only from its own camera's node (secured sessions).

    Links are learnt from zenoh's link events (``Link.auth_identifier``: the TLS certificate's
    common name). A sample is refused, and counted by reason, when it carries no source
    (``unattributed``), its source session has no direct link here (``unlinked``: relayed, or
    gone), that link's identity is not a camera's (``not_a_camera``), or the payload names
    another camera than the link's (``wrong_camera``).

    Args:
        session: the daemon's session (its link events are listened to).
    """

    def __init__(self, session: zenoh.Session):
        self.identities: dict[str, str | None] = {}  # session id -> certificate name
        self.links: dict[str, int] = {}  # identity -> links opened so far
        self.rejected = dict.fromkeys(REJECTS, 0)
        self.by_identity: dict[str, int] = {}  # rejected samples per sender identity
        self._lock = threading.Lock()
        self._listener = session.info.declare_link_events_listener(self._on_link, history=True)

    def _on_link(self, event) -> None:  # zenoh's thread
        link = event.link
        zid, who = str(link.zid), link.auth_identifier
        up = event.kind == zenoh.SampleKind.PUT
        with self._lock:
            if up:
                self.identities[zid] = who
                self.links[who or "none"] = self.links.get(who or "none", 0) + 1
            else:
                self.identities.pop(zid, None)
        role = role_of(who)
        if up and role in ("unknown", "none", "daemon"):
            log.warning(
                "zenoh link from %s (%s, %s): not a cell node that may send detections; "
                "nothing it puts reaches the planner", who or "a peer without a certificate",
                zid, link.dst,
            )  # fmt: skip
        elif up and role in ("viewer", "bridge"):
            log.info("zenoh link up: %s (%s: reads only, any detection it puts is refused; %s)",
                     who, role, zid)  # fmt: skip
        else:
            log.info("zenoh link %s: %s (%s, %s)", "up" if up else "down", who, role, zid)

    def admit(self, sample, payload: bytes) -> bool:
        """True when ``sample`` (whose payload is ``payload``) came from its camera's node."""
        src = sample.source_info
        if src is None:
            return self._reject("unattributed", None)
        with self._lock:
            zid = str(src.source_id.zid)
            if zid not in self.identities:
                return self._reject("unlinked", None)
            who = self.identities[zid]
        camera = camera_of(who)
        if camera is None:
            return self._reject("not_a_camera", who)
        try:
            obj = json.loads(payload)
        except Exception:  # not JSON: the intake refuses and counts it
            return True
        named = obj.get("camera") if isinstance(obj, dict) else None
        if (named or "base") != camera:  # absent or "base": the default camera (INTERFACES)
            return self._reject("wrong_camera", who)
        return True

    def _reject(self, reason: str, who: str | None) -> bool:
        self.rejected[reason] += 1
        key = who or "?"
        n = self.by_identity[key] = self.by_identity.get(key, 0) + 1
        if n == 1 or n % 1000 == 0:
            log.warning(
                "detection refused (%s) from %s: %d so far from it", reason,
                who or "a sender without a cell identity", n,
            )  # fmt: skip
        return False

    def as_dict(self) -> dict:
        with self._lock:
            linked = sorted({w or "none" for w in self.identities.values()})
        return {
            "linked": linked,
            "links_opened": dict(self.links),
            "rejected": {k: v for k, v in self.rejected.items() if v},
            "rejected_from": dict(self.by_identity),
        }

    def close(self) -> None:
        try:
            self._listener.undeclare()
        except Exception:
            pass


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
        insecure: open even a session another host reaches without authentication
            (``--insecure-zenoh``), warning every minute.

    Raises:
        ConfigError: such a session without ``insecure`` (one line naming the flag).
    """

    def __init__(self, conf: zenoh.Config, prefix: str, insecure: bool = False):
        self.security = session_security(conf)
        why = self.security.refusal()
        if why is not None and not insecure:
            from thinkfast.errors import ConfigError

            raise ConfigError("zenoh", None, why)
        self.session = open_session(conf)
        self.gate = SenderGate(self.session) if self.security.mode == "tls" else None
        self._nag: threading.Timer | None = None
        self._closed = False
        if why is not None:
            self._warn_insecure()
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

    def _warn_insecure(self) -> None:
        if self._closed:
            return
        sec = self.security
        if sec.mode == "tls":  # authenticated, but access control is off
            log.warning(
                "--insecure-zenoh: the zenoh session uses mutual TLS without access control: "
                "any node with a cell certificate can put detections in a camera's name "
                "(docs/SECURITY.md)"
            )
        else:
            open_to = [*sec.exposed, *(["multicast scouting"] if sec.multicast else [])]
            log.warning(
                "--insecure-zenoh: the zenoh session is open to other hosts without "
                "authentication (%s): anyone on the network can move the arm (docs/SECURITY.md)",
                ", ".join(open_to),
            )
        self._nag = threading.Timer(INSECURE_WARN_EVERY, self._warn_insecure)
        self._nag.daemon = True
        self._nag.start()

    def describe(self) -> dict:
        """Mode, endpoints, key prefix, session id and who guards it (for the start-up log)."""
        try:
            zid = str(self.session.info.zid())
        except Exception:
            zid = None
        return {**self._described, "prefix": self.prefix, "zid": zid,
                **self.security.as_dict()}  # fmt: skip

    def as_dict(self) -> dict:
        """The session's guard for the status: ``auth`` (tls, loopback, open) and, on a
        secured session, the linked identities and the refused detections."""
        out = {"auth": self.security.mode}
        if self.gate is not None:
            out.update(self.gate.as_dict())
        return out

    def drain(self, limit: int = 256) -> list[bytes]:
        """Payloads received since the last call (at most ``limit``), each from its camera's
        node on a secured session (the others counted by :class:`SenderGate`)."""
        return self.admitted(drain_samples(self.sub, limit))

    def admitted(self, samples) -> list[bytes]:
        """The payloads of ``samples`` that the gate admits (all of them on an unsecured
        session)."""
        out = []
        gate = self.gate
        for sample in samples:
            payload = sample.payload.to_bytes()
            if gate is None or gate.admit(sample, payload):
                out.append(payload)
        return out

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
        self._closed = True
        if self._nag is not None:
            self._nag.cancel()
        if self.gate is not None:
            self.gate.close()
        close_session(self.session)
