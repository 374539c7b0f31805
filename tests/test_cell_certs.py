"""thinkfast/cell/certs.py and ``thinkfast-cell certs``: the secured cell's CA, certificates and
zenoh configurations, checked with real X.509 parsing and real zenoh TLS sessions on loopback."""

from __future__ import annotations

import json
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from thinkfast.cell.certs import CellNodes, node_configs, write_cell
from thinkfast.contract.zenoh_auth import security_of
from thinkfast.contract.zenoh_session import (
    attributed_put,
    close_session,
    free_tcp_port,
    open_session,
    session_config,
)

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
EXAMPLES = ROOT / "examples" / "zenoh" / "secured"
# the examples' cell (a workstation at 192.168.125.10, the files in /etc/thinkfast/cell)
EXAMPLE_NODES = CellNodes(
    cameras=("base",), viewers=("status",), daemon_hosts=("192.168.125.10",),
    install_dir="/etc/thinkfast/cell",
)  # fmt: skip


def _cert(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


@pytest.fixture(scope="module")
def cell(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("cell")
    write_cell(d, CellNodes(cameras=("base", "side"), viewers=("status",)))
    return d


def test_every_node_has_a_certificate_of_the_cell_ca(cell):
    ca = _cert(cell / "ca.pem")
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for ident in ("daemon", "camera-base", "camera-side", "bridge-base", "viewer-status"):
        cert = _cert(cell / f"{ident}.pem")
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == ident
        cert.verify_directly_issued_by(ca)  # raises if not signed by the cell's CA
        eku = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
        assert {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH} <= set(eku)
        assert not cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
        mode = stat.S_IMODE((cell / f"{ident}.key").stat().st_mode)
        assert mode == 0o600, f"{ident}.key is {oct(mode)}"
    assert stat.S_IMODE((cell / "ca.key").stat().st_mode) == 0o600


def test_daemon_certificate_names_the_workstation(tmp_path):
    write_cell(tmp_path, CellNodes(cameras=("base",), daemon_hosts=("192.168.125.10", "ws.lab")))
    san = _cert(tmp_path / "daemon.pem").extensions.get_extension_for_class(
        x509.SubjectAlternativeName
    ).value  # fmt: skip
    assert "ws.lab" in san.get_values_for_type(x509.DNSName)
    assert "192.168.125.10" in {str(a) for a in san.get_values_for_type(x509.IPAddress)}
    conf = json.loads((tmp_path / "camera-base.json5").read_text().split("\n", 2)[2])
    assert conf["connect"]["endpoints"] == ["tls/192.168.125.10:7447"]
    daemon = json.loads((tmp_path / "daemon.json5").read_text().split("\n", 2)[2])
    assert daemon["listen"]["endpoints"] == ["tls/[::]:7447"]  # reachable: every interface


def test_every_generated_config_is_a_secured_session(cell):
    for path in cell.glob("*.json5"):
        conf = session_config(config_file=path)  # zenoh itself parses it
        from thinkfast.contract.zenoh_session import session_security

        sec = session_security(conf)
        assert sec.mode == "tls" and sec.acl, path.name


def test_running_again_keeps_the_ca_and_adds_a_camera(tmp_path):
    write_cell(tmp_path, CellNodes(cameras=("base",)))
    ca_before = (tmp_path / "ca.pem").read_bytes()
    base_before = (tmp_path / "camera-base.pem").read_bytes()
    written = write_cell(tmp_path, CellNodes(cameras=("base", "side")))
    assert "ca.pem" not in written and "camera-base.pem" not in written
    assert "camera-side.pem" in written
    assert (tmp_path / "ca.pem").read_bytes() == ca_before
    assert (tmp_path / "camera-base.pem").read_bytes() == base_before
    daemon = json.loads((tmp_path / "daemon.json5").read_text().split("\n", 2)[2])
    cams = {s["id"]: s for s in daemon["access_control"]["subjects"]}["cameras"]
    assert cams["cert_common_names"] == ["camera-base", "camera-side"]


def test_a_bad_camera_name_is_refused_in_one_line(tmp_path):
    proc = subprocess.run(
        [str(BIN / "thinkfast-cell"), "certs", str(tmp_path / "c"), "--camera", "a b"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "--camera 'a b'" in proc.stderr
    assert not (tmp_path / "c" / "ca.key").exists()


def test_the_examples_are_what_the_command_writes():
    """examples/zenoh/secured/ is the generator's output for the examples' cell (regenerate:
    ``thinkfast-cell certs DIR --viewer status --daemon-host 192.168.125.10 --install-dir
    /etc/thinkfast/cell`` and copy the .json5 files)."""
    configs = node_configs(EXAMPLE_NODES)
    assert sorted(p.stem for p in EXAMPLES.glob("*.json5")) == sorted(configs)
    for ident, conf in configs.items():
        text = (EXAMPLES / f"{ident}.json5").read_text()
        assert json.loads(text.split("\n", 2)[2]) == conf, ident
        assert security_of(conf).mode == "tls"
    assert not list(EXAMPLES.glob("*.key")) and not list(EXAMPLES.glob("*.pem"))


def _open(cell: Path, ident: str, **endpoints) -> zenoh.Session:
    return open_session(session_config(config_file=cell / f"{ident}.json5", **endpoints))


def _wait(cond, timeout=20.0) -> bool:
    end = time.time() + timeout
    while time.time() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


def test_real_tls_sessions_link_the_cell_and_refuse_another_ca(cell, tmp_path):
    """The generated configs work with zenoh itself: a camera links to the daemon with its
    name as the link's identity, and its detections arrive under the daemon's access control;
    a viewer's do not; a node of another CA gets no link at all."""
    port = free_tcp_port()
    ep = f"tls/127.0.0.1:{port}"
    daemon = _open(cell, "daemon", listen=[ep])
    links, got = [], []
    daemon.info.declare_link_events_listener(
        lambda e: links.append(e.link.auth_identifier), history=True
    )
    daemon.declare_subscriber("thinkfast/detections", lambda s: got.append(s.payload.to_bytes()))
    other = tmp_path / "other"
    write_cell(other, CellNodes(cameras=("base",)))
    sessions = []
    try:
        cam = _open(cell, "camera-base", connect=[ep], listen=[f"tls/127.0.0.1:{free_tcp_port()}"])
        viewer = _open(cell, "viewer-status", connect=[ep])
        sessions += [cam, viewer]
        assert _wait(lambda: {"camera-base", "viewer-status"} <= set(links))
        pub_cam = cam.declare_publisher("thinkfast/detections")
        pub_viewer = viewer.declare_publisher("thinkfast/detections")
        assert _wait(lambda: pub_cam.matching_status.matching)
        attributed_put(pub_cam)(b"from-camera")
        pub_viewer.put(b"from-viewer")
        assert _wait(lambda: b"from-camera" in got)
        time.sleep(0.3)  # the viewer's put had as long as the camera's to arrive
        assert b"from-viewer" not in got
        stranger = _open(other, "camera-base", connect=[ep],
                         listen=[f"tls/127.0.0.1:{free_tcp_port()}"])  # fmt: skip
        sessions.append(stranger)
        time.sleep(1.0)
        assert len(list(stranger.info.peers_zid())) == 0  # the handshake failed
        assert links.count("camera-base") == 1
    finally:
        for s in sessions:
            close_session(s)
        close_session(daemon)
