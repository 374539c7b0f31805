"""thinkfast/contract/zenoh_auth.py: who may speak on the cell's zenoh, and the verdict on a
session's configuration (read from real zenoh configurations)."""

from __future__ import annotations

import json

import pytest
import zenoh

from thinkfast.contract import zenoh_auth as za
from thinkfast.contract.zenoh_session import config_dict, session_config, session_security


@pytest.mark.parametrize(
    "endpoint, loopback",
    [
        ("tcp/127.0.0.1:7447", True),
        ("tcp/127.8.9.10:7447", True),
        ("tls/localhost:7447", True),
        ("tcp/[::1]:7447", True),
        ("unixsock-stream//tmp/z.sock", True),
        ("tcp/0.0.0.0:7447", False),
        ("tcp/[::]:0", False),
        ("tls/192.168.125.10:7447", False),
        ("tcp/workstation.lab:7447", False),
        ("udp/224.0.0.224:7446#iface=lo", False),
        ("tcp/127.0.0.1:7447?rel=1#iface=lo", True),
    ],
)
def test_loopback_endpoints(endpoint, loopback):
    assert za.is_loopback(endpoint) is loopback


@pytest.mark.parametrize(
    "identity, role, camera",
    [
        ("daemon", "daemon", None),
        ("camera-base", "camera", "base"),
        ("camera-side.2", "camera", "side.2"),
        ("bridge-base", "bridge", None),
        ("viewer-status", "viewer", None),
        ("camera-", "unknown", None),
        ("camera-a b", "unknown", None),
        ("intruder", "unknown", None),
        (None, "none", None),
        ("", "none", None),
    ],
)
def test_roles_from_certificate_names(identity, role, camera):
    assert za.role_of(identity) == role
    assert za.camera_of(identity) == camera


def _verdict(**kw):
    return session_security(session_config(**kw))


def test_zenoh_default_session_is_open_and_refused():
    """zenoh's own default peer listens on every interface and scouts by multicast."""
    sec = _verdict()
    assert sec.listen == ("tcp/[::]:0",) and sec.multicast
    assert sec.mode == "open"
    why = sec.refusal()
    assert "tcp/[::]:0" in why and "multicast" in why and "--insecure-zenoh" in why
    assert "\n" not in why


def test_loopback_without_multicast_is_the_demo_mode():
    sec = _verdict(listen=["tcp/127.0.0.1:7547"], connect=["tcp/localhost:7548"], multicast=False)
    assert sec.mode == "loopback" and sec.refusal() is None and sec.exposed == ()


def test_loopback_with_multicast_scouting_is_refused():
    sec = _verdict(listen=["tcp/127.0.0.1:7547"])  # multicast left at zenoh's default: on
    assert sec.mode == "open"
    assert "scouts by multicast" in sec.refusal() and "listens on" not in sec.refusal()


def test_an_exposed_plain_endpoint_is_refused_naming_it():
    sec = _verdict(listen=["tcp/0.0.0.0:7447"], connect=["tcp/10.0.0.2:7447"], multicast=False)
    why = sec.refusal()
    assert "listens on tcp/0.0.0.0:7447" in why and "connects to tcp/10.0.0.2:7447" in why


def _tls_conf(tmp_path, acl: bool = True, **tls_overrides) -> zenoh.Config:
    tls = za.tls_section("ca.pem", "n.pem", "n.key")
    tls.update(tls_overrides)
    conf = za.node_config(
        tls={k: v for k, v in tls.items() if v is not None},
        acl=za.daemon_acl("thinkfast", ["base"], []) if acl else {"enabled": False},
        listen=["tls/0.0.0.0:7447"],
    )
    path = tmp_path / "c.json5"
    path.write_text(json.dumps(conf))
    return session_config(config_file=path)


def test_mutual_tls_on_every_exposed_endpoint_is_authenticated(tmp_path):
    sec = session_security(_tls_conf(tmp_path))
    assert sec.mode == "tls" and sec.acl and sec.refusal() is None
    assert sec.as_dict()["auth"] == "tls"


def test_mutual_tls_without_access_control_is_refused(tmp_path):
    """The gate reads a source id the sender writes: only the access control stops a viewer's
    certificate from putting detections in a camera's name, so TLS alone does not do."""
    sec = session_security(_tls_conf(tmp_path, acl=False))
    assert sec.mode == "tls" and not sec.acl
    why = sec.refusal()
    assert why is not None and "without access control" in why and "--insecure-zenoh" in why


@pytest.mark.parametrize(
    "override, problem",
    [
        ({"enable_mtls": False}, "enable_mtls is not true"),
        ({"root_ca_certificate": None}, "no root_ca_certificate"),
        ({"listen_certificate": None}, "no listen_certificate"),
    ],
)
def test_tls_that_is_not_mutual_is_refused(tmp_path, override, problem):
    sec = session_security(_tls_conf(tmp_path, **override))
    assert sec.mode == "open"
    assert problem in sec.refusal() and "not mutual" in sec.refusal()


def test_a_plain_exposed_endpoint_beside_tls_is_refused(tmp_path):
    conf = _tls_conf(tmp_path)
    conf.insert_json5("listen/endpoints", json.dumps(["tls/0.0.0.0:7447", "tcp/0.0.0.0:7448"]))
    sec = session_security(conf)
    assert sec.mode == "open" and "tcp/0.0.0.0:7448" in sec.refusal()


def test_a_plain_loopback_endpoint_beside_tls_keeps_the_tls_mode(tmp_path):
    """A loopback peer without a certificate can read, but its detections are refused by the
    daemon's gate (no camera identity): the session stays secured."""
    conf = _tls_conf(tmp_path)
    conf.insert_json5("listen/endpoints", json.dumps(["tls/0.0.0.0:7447", "tcp/127.0.0.1:7448"]))
    assert session_security(conf).mode == "tls"


def test_config_dict_reads_what_zenoh_resolved():
    conf = session_config(listen=["tcp/127.0.0.1:7000"], multicast=False)
    d = config_dict(conf)
    assert d["listen"]["endpoints"] == ["tcp/127.0.0.1:7000"]
    assert d["scouting"]["multicast"]["enabled"] is False
    assert d["access_control"]["enabled"] is False


def test_daemon_acl_lets_only_cameras_put_detections():
    acl = za.daemon_acl("tf", ["base", "side"], ["status"])
    assert acl["enabled"] and acl["default_permission"] == "deny"
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    rules = {r["id"]: r for r in acl["rules"]}
    cam_policy = [p for p in acl["policies"] if "camera_detections" in p["rules"]]
    assert [p["subjects"] for p in cam_policy] == [["cameras"]]
    assert subjects["cameras"] == ["camera-base", "camera-side"]
    assert "viewer-status" in subjects["cell"] and "viewer-status" not in subjects["cameras"]
    assert rules["camera_detections"]["flows"] == ["ingress"]
    assert "tf/detections" in rules["camera_detections"]["key_exprs"]
    # the viewers' own side: only the daemon's puts come in
    viewer = za.viewer_acl()
    assert [s["cert_common_names"] for s in viewer["subjects"]] == [["daemon"]]
