"""Who may speak on the cell's zenoh: node identities, the access-control lists and zenoh
configurations of a secured cell, and the verdict on a session's configuration.

A secured cell (docs/SECURITY.md) runs zenoh over TLS with mutual authentication: every node
holds a certificate from the cell's own CA, and the certificate's common name is the node's
identity, which zenoh reports for each link (``Link.auth_identifier``) and matches in its access
control (``cert_common_names``). The names say the role:

=================  ==========================================================================
``daemon``         ``thinkfast-run``: reads detections, puts status and setpoint mirrors
``camera-<id>``    the detector of camera ``<id>`` (``base`` for the default camera): the only
                   nodes that may put detections, each only its own camera's
``bridge-<id>``    the ZED bridge of camera ``<id>``: puts frames for that camera's detector
``viewer-<name>``  reads only (``thinkfast-run status``, a ROS 2 bridge, a dashboard)
=================  ==========================================================================

Nothing here opens a session: the functions build and judge plain JSON-able dicts (zenoh's
configuration schema), so the daemon, the certificate tool and the tests share one reading.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass

from thinkfast.contract import keys

DAEMON = "daemon"
ROLES = ("daemon", "camera", "bridge", "viewer")
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")  # a camera id's alphabet (docs/INTERFACES.md)
SECURE_PROTOCOLS = ("tls", "quic")  # zenoh links that carry the TLS identity
LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe", "vsock")  # never leave the host


def camera_identity(camera: str) -> str:
    """The certificate name of camera ``camera``'s detector node."""
    return f"camera-{camera}"


def bridge_identity(camera: str) -> str:
    """The certificate name of camera ``camera``'s ZED bridge node."""
    return f"bridge-{camera}"


def viewer_identity(name: str) -> str:
    """The certificate name of a read-only node."""
    return f"viewer-{name}"


def role_of(identity: str | None) -> str:
    """``daemon``, ``camera``, ``bridge`` or ``viewer`` for a cell identity; ``none`` for a
    link without one (plain TCP, loopback); ``unknown`` for a name no cell node has."""
    if not identity:
        return "none"
    if identity == DAEMON:
        return "daemon"
    role, _, rest = identity.partition("-")
    if role in ("camera", "bridge", "viewer") and _NAME.match(rest):
        return role
    return "unknown"


def camera_of(identity: str | None) -> str | None:
    """The camera id a ``camera-<id>`` identity speaks for, or None."""
    if role_of(identity) != "camera":
        return None
    return identity.partition("-")[2]  # type: ignore[union-attr]


def check_node_name(name: str, what: str) -> str:
    """``name`` if it is a valid camera or viewer id, else ValueError naming ``what``."""
    if not _NAME.match(name):
        raise ValueError(f"{what} {name!r} is not 1-64 of A-Z a-z 0-9 _ . -")
    return name


# ---------------------------------------------------------------------------------------------
# access control (zenoh's ``access_control`` section)


def detection_keys(prefix: str) -> list[str]:
    """Key expressions a camera puts on: the JSON detections and their ROS 2 topics (any
    domain, rmw_zenoh's layout)."""
    return [keys.detections(prefix), f"*/{prefix}/detections/**", f"*/{prefix}/detections_3d/**"]


def _acl(rules: list[dict], subjects: list[dict], policies: list[dict]) -> dict:
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


_DECLARE = [
    "declare_subscriber",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]


def daemon_acl(prefix: str, cameras: list[str], viewers: list[str]) -> dict:
    """The daemon's access control: only the cameras' nodes may put detections in; every cell
    node may subscribe (declarations in and out) and receive what the daemon puts; nothing
    else comes in (default deny), and no link without a cell identity gets anything."""
    cams = [camera_identity(c) for c in cameras]
    cell = [DAEMON, *cams, *(viewer_identity(v) for v in viewers)]
    return _acl(
        rules=[
            {"id": "camera_detections", "messages": ["put"], "flows": ["ingress"],
             "permission": "allow", "key_exprs": detection_keys(prefix)},
            {"id": "cell_declarations", "messages": _DECLARE, "flows": ["ingress", "egress"],
             "permission": "allow", "key_exprs": ["**"]},
            {"id": "daemon_puts", "messages": ["put"], "flows": ["egress"],
             "permission": "allow", "key_exprs": ["**"]},
        ],
        subjects=[{"id": "cameras", "cert_common_names": cams},
                  {"id": "cell", "cert_common_names": cell}],
        policies=[{"rules": ["camera_detections"], "subjects": ["cameras"]},
                  {"rules": ["cell_declarations", "daemon_puts"], "subjects": ["cell"]}],
    )  # fmt: skip


def camera_acl(prefix: str, camera: str) -> dict:
    """A camera detector's access control: it puts detections to the daemon and takes its own
    bridge's frames and the daemon's status; it believes no one else's puts. The status comes
    in so that a camera node can tell the daemon is there (the simulated IRC5 throwing as the
    camera waits for it, and stops on its silence: :class:`thinkfast.sim.watchdog.Watchdog`)."""
    return _acl(
        rules=[
            {"id": "detections_out", "messages": ["put"], "flows": ["egress"],
             "permission": "allow", "key_exprs": detection_keys(prefix)},
            {"id": "status_in", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [keys.status(prefix)]},
            {"id": "frames_in", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [f"{prefix}/camera/**"]},
            {"id": "declarations", "messages": _DECLARE, "flows": ["ingress", "egress"],
             "permission": "allow", "key_exprs": ["**"]},
        ],
        subjects=[{"id": "daemon", "cert_common_names": [DAEMON]},
                  {"id": "bridge", "cert_common_names": [bridge_identity(camera)]}],
        policies=[{"rules": ["detections_out", "status_in", "declarations"],
                   "subjects": ["daemon"]},
                  {"rules": ["frames_in", "declarations"], "subjects": ["bridge"]}],
    )  # fmt: skip


def bridge_acl(prefix: str, camera: str) -> dict:
    """A ZED bridge's access control: frames out to its camera's detector, nothing in."""
    return _acl(
        rules=[
            {"id": "frames_out", "messages": ["put"], "flows": ["egress"], "permission": "allow",
             "key_exprs": [f"{prefix}/camera/**"]},
            {"id": "declarations", "messages": _DECLARE, "flows": ["ingress", "egress"],
             "permission": "allow", "key_exprs": ["**"]},
        ],
        subjects=[{"id": "detector", "cert_common_names": [camera_identity(camera)]}],
        policies=[{"rules": ["frames_out", "declarations"], "subjects": ["detector"]}],
    )  # fmt: skip


def viewer_acl() -> dict:
    """A read-only node's access control: it takes puts from the daemon alone and puts
    nothing."""
    return _acl(
        rules=[
            {"id": "daemon_puts", "messages": ["put"], "flows": ["ingress"],
             "permission": "allow", "key_exprs": ["**"]},
            {"id": "declarations", "messages": _DECLARE, "flows": ["ingress", "egress"],
             "permission": "allow", "key_exprs": ["**"]},
        ],
        subjects=[{"id": "daemon", "cert_common_names": [DAEMON]}],
        policies=[{"rules": ["daemon_puts", "declarations"], "subjects": ["daemon"]}],
    )  # fmt: skip


def tls_section(ca: str, cert: str, key: str) -> dict:
    """zenoh's ``transport.link.tls``: mutual TLS with the cell's CA, this node's certificate
    and key on both sides of a link, the peer's name checked when connecting."""
    return {
        "root_ca_certificate": ca,
        "enable_mtls": True,
        "listen_certificate": cert,
        "listen_private_key": key,
        "connect_certificate": cert,
        "connect_private_key": key,
        "verify_name_on_connect": True,
    }


def node_config(
    *,
    tls: dict,
    acl: dict,
    listen: list[str] = (),  # type: ignore[assignment]
    connect: list[str] = (),  # type: ignore[assignment]
) -> dict:
    """A secured node's zenoh configuration: peer, no multicast scouting (the cell's nodes are
    named by endpoint), TLS and access control."""
    conf: dict = {
        "mode": "peer",
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": tls}},
        "access_control": acl,
    }
    conf["listen"] = {"endpoints": list(listen)}  # none: zenoh's default is every interface
    if connect:
        conf["connect"] = {"endpoints": list(connect)}
    return conf


# ---------------------------------------------------------------------------------------------
# the verdict on a session's configuration


def endpoint_host(endpoint: str) -> tuple[str, str]:
    """``(protocol, host)`` of a zenoh endpoint ``proto/host:port[?..][#..]``; the host of a
    local-socket endpoint is ``""``."""
    proto, _, rest = endpoint.partition("/")
    if proto in LOCAL_PROTOCOLS:
        return proto, ""
    rest = rest.split("?", 1)[0].split("#", 1)[0]
    if rest.startswith("["):  # [v6]:port
        return proto, rest[1:].split("]", 1)[0]
    return proto, rest.rsplit(":", 1)[0]


def is_loopback(endpoint: str) -> bool:
    """True when ``endpoint`` can only be reached from this host (loopback address,
    ``localhost``, or a local socket)."""
    proto, host = endpoint_host(endpoint)
    if proto in LOCAL_PROTOCOLS:
        return True
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # another host name, or 0.0.0.0 / [::] (every interface)


def _endpoints(section, mode: str) -> list[str]:
    """A ``listen``/``connect`` ``endpoints`` value: a list, or zenoh's per-mode dict."""
    if isinstance(section, dict):
        section = section.get(mode) or []
    return [str(e) for e in section or []]


@dataclass(frozen=True)
class SessionSecurity:
    """What a zenoh configuration exposes and what guards it.

    Attributes:
        listen, connect: the endpoints the session will use (zenoh's defaults when unset).
        multicast: multicast scouting on (zenoh's default for a peer).
        tls_problems: what keeps the TLS section from authenticating both ends (empty: mutual
            TLS with the cell's CA is configured).
        acl: zenoh's access control is on with default deny.
    """

    listen: tuple[str, ...]
    connect: tuple[str, ...]
    multicast: bool
    tls_problems: tuple[str, ...]
    acl: bool

    @property
    def exposed(self) -> tuple[str, ...]:
        """Endpoints another host may reach."""
        return tuple(e for e in (*self.listen, *self.connect) if not is_loopback(e))

    @property
    def uses_tls(self) -> bool:
        return any(endpoint_host(e)[0] in SECURE_PROTOCOLS for e in (*self.listen, *self.connect))

    @property
    def authenticated(self) -> bool:
        """Mutual TLS configured, and every endpoint another host may reach is a TLS one."""
        return (
            self.uses_tls
            and not self.tls_problems
            and all(endpoint_host(e)[0] in SECURE_PROTOCOLS for e in self.exposed)
        )

    @property
    def mode(self) -> str:
        """``tls`` (authenticated), ``loopback`` (nothing another host reaches, no multicast
        scouting) or ``open``."""
        if self.authenticated:
            return "tls"
        if not self.exposed and not self.multicast:
            return "loopback"
        return "open"

    def refusal(self) -> str | None:
        """Why a session that moves the arm must not open with this configuration (one line
        naming the override), or None when it may.

        Mutual TLS without access control is refused too: the daemon's sender gate reads a
        sample's source id, which the sender writes, so only zenoh's access control (puts on
        the detection keys from camera certificates only) keeps a node holding any cell
        certificate from putting detections in a camera's name."""
        if self.mode == "tls" and not self.acl:
            return (
                "the session uses mutual TLS without access control (access_control enabled "
                "with default_permission deny): any node with a cell certificate could put "
                "detections in a camera's name. Use the daemon configuration thinkfast-cell "
                "certs writes (docs/SECURITY.md), or --insecure-zenoh"
            )
        if self.mode != "open":
            return None
        what = []
        for verb, ends in (("listens on", self.listen), ("connects to", self.connect)):
            out = [e for e in ends if not is_loopback(e)]
            if out:
                what.append(f"{verb} {', '.join(out)}")
        if self.multicast:
            what.append("scouts by multicast")
        if self.uses_tls and self.tls_problems:
            why = "with a TLS that is not mutual (" + "; ".join(self.tls_problems) + ")"
        else:
            why = "without authentication"
        return (
            f"the session {' and '.join(what)} {why}: any host on the network could move "
            "the arm. Give a secured --zenoh-config (thinkfast-cell certs, docs/SECURITY.md), "
            "loopback endpoints only (--zenoh-listen tcp/127.0.0.1:PORT), or --insecure-zenoh"
        )

    def as_dict(self) -> dict:
        return {
            "auth": self.mode,
            "exposed": list(self.exposed),
            "multicast": self.multicast,
            "access_control": self.acl,
        }


def security_of(conf: dict) -> SessionSecurity:
    """The verdict on zenoh configuration ``conf`` (a dict in zenoh's schema, e.g. from
    ``zenoh.Config.get_json``; unset values take zenoh's defaults for a peer)."""
    mode = conf.get("mode") or "peer"
    listen = _endpoints((conf.get("listen") or {}).get("endpoints"), mode)
    if (conf.get("listen") or {}).get("endpoints") is None:
        listen = ["tcp/[::]:7447"] if mode == "router" else ["tcp/[::]:0"]  # zenoh's default
    connect = _endpoints((conf.get("connect") or {}).get("endpoints"), mode)
    multicast = ((conf.get("scouting") or {}).get("multicast") or {}).get("enabled")
    multicast = mode != "client" if multicast is None else bool(multicast)
    tls = ((conf.get("transport") or {}).get("link") or {}).get("tls") or {}
    problems = []
    if not (tls.get("root_ca_certificate") or tls.get("root_ca_certificate_base64")):
        problems.append("no root_ca_certificate")
    if not tls.get("enable_mtls"):
        problems.append("enable_mtls is not true")
    secure_listen = any(endpoint_host(e)[0] in SECURE_PROTOCOLS for e in listen)
    secure_connect = any(endpoint_host(e)[0] in SECURE_PROTOCOLS for e in connect)
    for side, used in (("listen", secure_listen), ("connect", secure_connect)):
        if not used:
            continue
        for part in ("certificate", "private_key"):
            k = f"{side}_{part}"
            if not (tls.get(k) or tls.get(f"{k}_base64")):
                problems.append(f"no {k}")
    acl = conf.get("access_control") or {}
    acl_on = bool(acl.get("enabled")) and (acl.get("default_permission") or "deny") == "deny"
    return SessionSecurity(tuple(listen), tuple(connect), multicast, tuple(problems), acl_on)
