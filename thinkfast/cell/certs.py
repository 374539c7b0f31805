"""The secured cell's keys: its own certificate authority, one certificate per zenoh node, and
each node's zenoh configuration (mutual TLS and access control; docs/SECURITY.md).

``thinkfast-cell certs DIR --camera base --viewer status`` writes into ``DIR``::

    ca.pem  ca.key                       the cell's CA (keep ca.key off the cell's hosts)
    daemon.pem  daemon.key  daemon.json5 the workstation's daemon (listens)
    camera-base.{pem,key,json5}          the detector of camera "base" (connects)
    bridge-base.{pem,key,json5}          its ZED bridge (connects to the detector's host)
    viewer-status.{pem,key,json5}        a read-only node (thinkfast-run status, ROS 2 bridge)

Run it again with more ``--camera``/``--viewer`` to add nodes: the CA and the certificates
already there are kept, every configuration is written again (the daemon's access control names
every camera). Keys are EC P-256, written owner-only (0600). The identity of a node is its
certificate's common name (:mod:`thinkfast.contract.zenoh_auth`).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from thinkfast.contract import zenoh_auth as za

CA_NAME = "thinkfast cell CA"
DEFAULT_DAYS = 730
DEFAULT_PORT = 7447
BRIDGE_PORT = 7448  # the first camera's detector listens here for its bridge (loopback)


@dataclass(frozen=True)
class CellNodes:
    """The nodes of a secured cell and where the daemon is reached.

    Attributes:
        cameras: camera ids (``base`` is the default camera).
        viewers: read-only node names.
        daemon_hosts: names and addresses of the workstation, in the daemon's certificate; the
            first is the one the other nodes connect to.
        port: the daemon's zenoh TLS port.
        prefix: the key prefix (``--key-prefix``).
        install_dir: where the files will be on each node (the paths in the configurations).
    """

    cameras: tuple[str, ...]
    viewers: tuple[str, ...] = ()
    daemon_hosts: tuple[str, ...] = ("127.0.0.1",)
    port: int = DEFAULT_PORT
    prefix: str = "thinkfast"
    install_dir: str = ""

    def identities(self) -> list[str]:
        return [
            za.DAEMON,
            *(za.camera_identity(c) for c in self.cameras),
            *(za.bridge_identity(c) for c in self.cameras),
            *(za.viewer_identity(v) for v in self.viewers),
        ]

    @property
    def daemon_listen(self) -> str:
        """Where the daemon listens: loopback when every name of it is a loopback one, else
        every interface."""
        local = all(za.is_loopback(f"tls/{_host_part(h)}:{self.port}") for h in self.daemon_hosts)
        return f"tls/127.0.0.1:{self.port}" if local else f"tls/[::]:{self.port}"

    @property
    def daemon_endpoint(self) -> str:
        return f"tls/{_host_part(self.daemon_hosts[0])}:{self.port}"


def _host_part(host: str) -> str:
    try:
        return f"[{host}]" if ipaddress.ip_address(host).version == 6 else host
    except ValueError:
        return host


def _now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _key_pem(key) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _load_key(path: Path):
    return serialization.load_pem_private_key(path.read_bytes(), password=None)


def make_ca(directory: Path, days: int = DEFAULT_DAYS, name: str = CA_NAME):
    """A new CA in ``directory`` (``ca.pem``, ``ca.key``); returns ``(certificate, key)``."""
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = _now()
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )  # fmt: skip
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), False)
        .sign(key, hashes.SHA256())
    )
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "ca.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    _write_private(directory / "ca.key", _key_pem(key))
    return cert, key


def load_ca(directory: Path):
    """The CA of ``directory``: ``(certificate, key)``."""
    cert = x509.load_pem_x509_certificate((directory / "ca.pem").read_bytes())
    return cert, _load_key(directory / "ca.key")


def make_node_cert(
    directory: Path, identity: str, ca, hosts: tuple[str, ...] = (), days: int = DEFAULT_DAYS
) -> None:
    """``<identity>.pem`` and ``<identity>.key`` in ``directory``: a certificate for both ends
    of a TLS link (server and client), common name ``identity``, the names ``hosts`` (DNS
    names or IP addresses) and ``identity`` itself as subject alternative names."""
    ca_cert, ca_key = ca
    key = ec.generate_private_key(ec.SECP256R1())
    names: list[x509.GeneralName] = [x509.DNSName(identity)]
    for h in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    now = _now()
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, identity)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(min(now + dt.timedelta(days=days), ca_cert.not_valid_after_utc))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), False
        )
        .sign(ca_key, hashes.SHA256())
    )
    (directory / f"{identity}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    _write_private(directory / f"{identity}.key", _key_pem(key))


def node_configs(nodes: CellNodes) -> dict[str, dict]:
    """Each node's zenoh configuration (identity -> dict in zenoh's schema)."""
    base = nodes.install_dir.rstrip("/")

    def tls(identity: str) -> dict:
        return za.tls_section(f"{base}/ca.pem", f"{base}/{identity}.pem", f"{base}/{identity}.key")

    prefix, daemon_ep = nodes.prefix, nodes.daemon_endpoint
    out = {
        za.DAEMON: za.node_config(
            tls=tls(za.DAEMON),
            acl=za.daemon_acl(prefix, list(nodes.cameras), list(nodes.viewers)),
            listen=[nodes.daemon_listen],
        )
    }
    for i, cam in enumerate(nodes.cameras):
        ident, bridge = za.camera_identity(cam), za.bridge_identity(cam)
        # the detector connects to the daemon and takes its bridge's frames on a loopback port
        # of the camera host (the bridge runs beside it)
        frames = f"tls/127.0.0.1:{BRIDGE_PORT + i}"
        out[ident] = za.node_config(
            tls=tls(ident), acl=za.camera_acl(prefix, cam), connect=[daemon_ep], listen=[frames]
        )
        out[bridge] = za.node_config(
            tls=tls(bridge), acl=za.bridge_acl(prefix, cam), connect=[frames]
        )
    for v in nodes.viewers:
        ident = za.viewer_identity(v)
        out[ident] = za.node_config(tls=tls(ident), acl=za.viewer_acl(), connect=[daemon_ep])
    return out


def _json5_text(identity: str, conf: dict) -> str:
    head = (
        f"// zenoh configuration of the secured cell's node {identity!r}, written by "
        "`thinkfast-cell certs` (docs/SECURITY.md).\n// Its certificate's common name is its "
        "identity: the daemon admits detections only from camera-<id> nodes.\n"
    )
    return head + json.dumps(conf, indent=2) + "\n"


def write_cell(directory: Path, nodes: CellNodes, days: int = DEFAULT_DAYS) -> list[str]:
    """The CA (made when ``directory`` has none), a certificate for each node that has none,
    and every node's configuration. Returns the files written."""
    for c in nodes.cameras:
        za.check_node_name(c, "--camera")
    for v in nodes.viewers:
        za.check_node_name(v, "--viewer")
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    if (directory / "ca.pem").exists() and (directory / "ca.key").exists():
        ca = load_ca(directory)
    else:
        ca = make_ca(directory, days)
        written += ["ca.pem", "ca.key"]
    if not nodes.install_dir:
        nodes = CellNodes(**{**nodes.__dict__, "install_dir": str(directory.resolve())})
    for ident in nodes.identities():
        if (directory / f"{ident}.pem").exists() and (directory / f"{ident}.key").exists():
            continue
        # every node answers on loopback names too (the detector to its bridge)
        hosts = (*(nodes.daemon_hosts if ident == za.DAEMON else ()), "localhost", "127.0.0.1")
        make_node_cert(directory, ident, ca, tuple(dict.fromkeys(hosts)), days)
        written += [f"{ident}.pem", f"{ident}.key"]
    for ident, conf in node_configs(nodes).items():
        (directory / f"{ident}.json5").write_text(_json5_text(ident, conf))
        written.append(f"{ident}.json5")
    return written
