"""Only the cell's own cameras move the arm: the real daemon on a secured session (mutual TLS and
zenoh access control from ``thinkfast-cell certs``), a simulated IRC5 over real EGM, and real
zenoh sessions on loopback as intruders and as the cell's camera.

Each intruder puts a whole fabricated throw (a still hold, then a flight at a reachable point)
on the detection key: a session without credentials (plain TCP, and TLS without a client
certificate), a camera certificate of another CA, valid cell certificates that are not a
camera's (the status viewer, the camera's frame bridge; run, as their key's thief would, with
their own configuration's access control off), and the camera's own certificate
putting samples without a source or in another camera's name. Not one detection may reach the
planner, no throw may start and the arm must not leave home; each rejection is in the status
(the sender gate's counts, the links it saw) or the daemon's log. The camera's own throw over
the same session is then blocked, as on an unsecured loopback session.

The command line's guard (``thinkfast-run`` refuses an exposed session without authentication
in one line, starts and warns with ``--insecure-zenoh``) is checked on processes too.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from tests.conftest import assert_one_line_error
from tests.daemon_harness import ballistic_throw, free_port, publish_throw, until
from thinkfast.cell.certs import CellNodes, write_cell
from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import (
    attributed_put,
    close_session,
    free_tcp_port,
    open_session,
    session_config,
)
from thinkfast.sim.controller import ServoConfig, SimController
from thinkfast.sim.controller_runner import ControllerRunner
from thinkfast.sim.realtime import daemon_log, daemon_says, stop_daemon, wait_port

BIN = Path(sys.executable).parent
AIM, FLIGHT, RELEASE = (0.25, 1.25), 0.8, (7.8, -0.2, 1.5)  # 0.3 m from home: the tree blocks it
START = 120.0  # s for the daemon to serve on a slow host (imports, tree, TLS session)
pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module")
def cells(tmp_path_factory) -> tuple[Path, Path, int]:
    """The cell (camera base, viewer status) and a stranger's cell of another CA, both made by
    the command's own code, with the daemon on a free port."""
    port = free_tcp_port()
    cell, other = tmp_path_factory.mktemp("cell"), tmp_path_factory.mktemp("other")
    write_cell(cell, CellNodes(cameras=("base",), viewers=("status",), port=port))
    write_cell(other, CellNodes(cameras=("base",), port=port))
    return cell, other, port


def _node(cell: Path, identity: str, own_acl: bool = True, **endpoints) -> zenoh.Session:
    """A node of ``cell`` as its generated configuration makes it (a camera's own listen port,
    for its bridge, moved to a free one); ``own_acl=False``: with the node's own access control
    off, as the holder of a key would run it to put what its configuration forbids."""
    if identity.startswith("camera-"):
        endpoints.setdefault("listen", [f"tls/127.0.0.1:{free_tcp_port()}"])
    path = cell / f"{identity}.json5"
    if not own_acl:
        conf = json.loads(path.read_text().split("\n", 2)[2])  # after the two comment lines
        conf["access_control"] = {"enabled": False}
        path = cell / f"{identity}-no-acl.json5"
        path.write_text(json.dumps(conf))
    return open_session(session_config(config_file=path, **endpoints))


def _no_certificate(cell: Path, port: int) -> zenoh.Session:
    """TLS with the cell's CA (so it can check the daemon) but no certificate of its own."""
    path = cell.parent / f"nocert-{cell.name}.json5"
    path.write_text(json.dumps({
        "mode": "peer", "scouting": {"multicast": {"enabled": False}},
        "listen": {"endpoints": []}, "connect": {"endpoints": [f"tls/127.0.0.1:{port}"]},
        "transport": {"link": {"tls": {"root_ca_certificate": str(cell / "ca.pem")}}},
    }))  # fmt: skip
    return open_session(session_config(config_file=path))


class Thrower:
    """Puts detections from ``session``: attributed (the source the project's camera nodes
    attach) or bare, each payload's ``camera`` field set to ``camera`` when given."""

    def __init__(self, session: zenoh.Session, attributed: bool = True, camera: str | None = None):
        self.session = session
        self.pub = session.declare_publisher(
            keys.detections("thinkfast"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self.put = attributed_put(self.pub) if attributed else self.pub.put
        self.camera = camera
        self.sent = 0

    def publish(self, payload: bytes) -> None:
        if self.camera is not None:
            obj = json.loads(payload)
            obj["camera"] = self.camera
            payload = json.dumps(obj).encode()
        self.put(payload)
        self.sent += 1

    def throw(self, seed: int) -> float:
        """One fabricated throw at AIM (hold, flight); its release time [s, wall]."""
        t_release = time.time() + 0.5
        _, _, at = ballistic_throw(AIM, FLIGHT, t_release, RELEASE)
        publish_throw(self, at, t_release, FLIGHT, hold=0.4, seed=seed)
        return t_release


class SecuredDaemon:
    """``thinkfast-run`` with the cell's daemon configuration (TLS, access control) and nothing
    else on zenoh, a simulated IRC5 over EGM, and the cell's viewer reading its status."""

    def __init__(self, tree: Path, cell: Path, port: int, record: Path, home):
        self.egm_port, self.port, self.record = free_port(), port, record
        cmd = [str(BIN / "thinkfast-run"), "--tree", str(tree),
               "--egm-bind", f"127.0.0.1:{self.egm_port}",
               "--zenoh-config", str(cell / "daemon.json5"), "--record", str(record)]  # fmt: skip
        log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(cmd, stderr=log, text=True)
        self.proc.log = log  # type: ignore[attr-defined]
        self.runner = self.viewer = None
        self.status: list[dict] = []
        try:
            wait_port(self.proc, port, timeout=START)
            assert daemon_says(self.proc, "serving EGM on", START), daemon_log(self.proc)
            self.viewer = _node(cell, "viewer-status")
            self.viewer.declare_subscriber(
                keys.status("thinkfast"),
                lambda s: self.status.append(json.loads(s.payload.to_bytes())),
            )
            assert until(lambda: bool(self.status), START), "no status through the viewer"
            self.sim = SimController(ServoConfig(), q0=home)
            self.runner = ControllerRunner(self.sim, ("127.0.0.1", self.egm_port)).start()
        except BaseException:
            self.stop()
            raise

    def last(self) -> dict:
        return self.status[-1]

    def log(self) -> str:
        return daemon_log(self.proc)

    def stop(self) -> tuple[int | None, str]:
        code = stop_daemon(self.proc, timeout=20.0)
        if self.runner is not None:
            self.runner.stop()
            self.runner.join(2.0)
        if self.viewer is not None:
            close_session(self.viewer)
        return code, daemon_log(self.proc)

    def egm_rows(self) -> np.ndarray:
        import h5py

        with h5py.File(self.record) as f:
            return f["egm"][:]


def _links(session: zenoh.Session) -> int:
    return len(list(session.info.peers_zid()))


def test_intruders_move_nothing_and_the_cameras_throw_is_blocked(
    cells, small_tree_015, tmp_path, robot, kin
):
    from thinkfast.sim.judge import judge
    from thinkfast.sim.throws import ThrowConfig, make_throw

    cell, other, port = cells
    run = SecuredDaemon(small_tree_015, cell, port, tmp_path / "rec.h5", robot.home)
    sessions: list[zenoh.Session] = []
    linked: dict[str, bool] = {}
    sent: dict[str, int] = {}
    try:
        assert run.last()["zenoh"]["auth"] == "tls"
        assert until(lambda: run.last().get("egm_connected"), START), run.last()
        intruders = {  # name -> (session, attributed, camera field)
            "plain_tcp": (lambda: open_session(session_config(
                connect=[f"tcp/127.0.0.1:{port}"], listen=[], multicast=False)), True, None),
            "tls_without_certificate": (lambda: _no_certificate(cell, port), True, None),
            "other_ca_camera": (lambda: _node(other, "camera-base", False), True, None),
            "viewer_certificate": (lambda: _node(cell, "viewer-status", False), True, None),
            "bridge_certificate": (lambda: _node(cell, "bridge-base", False, connect=[
                f"tls/127.0.0.1:{port}"]), True, None),
            "camera_unattributed": (lambda: _node(cell, "camera-base"), False, None),
            "camera_as_another": (lambda: _node(cell, "camera-base"), True, "side"),
        }  # fmt: skip
        for seed, (name, (open_it, attributed, camera)) in enumerate(intruders.items()):
            s = open_it()
            sessions.append(s)
            # the certificate holders of the cell link (the handshake passes), the others do
            # not: wait for the link where one is due, give the others as long
            until(lambda s=s: _links(s) > 0, 3.0, poll=0.05)
            linked[name] = _links(s) > 0
            thrower = Thrower(s, attributed, camera)
            thrower.throw(seed)
            sent[name] = thrower.sent
            time.sleep(0.3)  # the last samples in flight arrive before the next intruder
            close_session(s)
            sessions.pop()
        time.sleep(1.0)  # a status after the last intruder's samples
        seen = run.last()
        # the cell's camera, over the same session
        cam = _node(cell, "camera-base")
        sessions.append(cam)
        assert until(lambda: _links(cam) > 0, 20.0), "the camera's node never linked"
        thrower = Thrower(cam)
        assert until(lambda: thrower.pub.matching_status.matching, 20.0)
        t_release = thrower.throw(seed=99)
        assert until(lambda: run.last()["throws"] == 1 and run.last()["state"] == "idle", 20.0)
        final = run.last()
    finally:
        for s in sessions:
            close_session(s)
        code, log = run.stop()
        print(log)
    assert code == 0, log
    print("linked:", linked, "sent:", sent, "zenoh status:", seen["zenoh"], sep="\n")
    assert all(n > 30 for n in sent.values()), sent  # each put a whole throw
    # who got a link at all: only holders of the cell's certificates
    assert linked == {"plain_tcp": False, "tls_without_certificate": False,
                      "other_ca_camera": False, "viewer_certificate": True,
                      "bridge_certificate": True, "camera_unattributed": True,
                      "camera_as_another": True}  # fmt: skip
    # nothing reached the planner: no detection accepted, no throw, the arm at home throughout
    assert seen["detections"]["accepted"] == 0, seen["detections"]
    assert seen["throws"] == 0 and seen["state"] == "idle"
    rows = run.egm_rows()
    intruded = rows[rows[:, 0] < t_release - 0.5]
    assert len(intruded) > 1000  # the controller was served all along (4 ms cycles)
    assert np.allclose(intruded[:, 8:14], robot.home, atol=1e-9), "a setpoint left home"
    assert np.allclose(intruded[:, 14:20], 0.0, atol=1e-9)
    assert np.allclose(intruded[:, 2:8], robot.home, atol=1e-6)  # and the arm stayed there
    assert log.count("throw_start") == 1  # the camera's throw only
    # the rejections, in the status: the gate's counts by reason and by sender identity, the
    # links it saw; in the log: the non-camera nodes' links
    gate = seen["zenoh"]
    assert gate["rejected"]["unattributed"] == sent["camera_unattributed"]
    assert gate["rejected"]["wrong_camera"] == sent["camera_as_another"]
    assert gate["rejected_from"]["camera-base"] == sent["camera_as_another"]
    # the viewer's and the bridge's puts never reached the gate: the access control dropped
    # them at the daemon's ingress (without it they would be counted not_a_camera here)
    assert set(gate["rejected"]) == {"unattributed", "wrong_camera"}, gate
    assert {"viewer-status", "bridge-base", "camera-base"} <= set(gate["links_opened"])
    assert "other" not in json.dumps(gate)  # no link from the stranger's CA
    assert "zenoh link up: viewer-status (viewer: reads only" in log
    assert "zenoh link up: bridge-base (bridge: reads only" in log
    assert "detection refused (wrong_camera) from camera-base" in log
    assert "detection refused (unattributed)" in log
    # the camera's throw: accepted and blocked, as on a loopback session
    assert final["detections"]["accepted"] > 30
    throw = make_throw(ThrowConfig(drag_coefficient=0.0), np.array(RELEASE), AIM, FLIGHT, 0.0)
    verdict = judge(throw, rows[:, 0], rows[:, 2:8], kin, 0.8, 0.0335, t_release_wall=t_release)
    assert verdict.blocked, verdict


def _run_cli(*args: str, timeout: float = START) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "thinkfast-run"), *args], capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def test_an_exposed_session_without_authentication_is_refused_in_one_line(small_tree_015):
    port = free_tcp_port()
    for how in (["--zenoh-listen", f"tcp/0.0.0.0:{port}"],
                ["--zenoh-listen", f"tcp/127.0.0.1:{port}",
                 "--zenoh-connect", f"tcp/192.0.2.1:{port}"]):  # fmt: skip
        done = _run_cli("--tree", str(small_tree_015), "--egm-bind", f"127.0.0.1:{free_port()}",
                        *how)  # fmt: skip
        assert_one_line_error(done, "without authentication", "--insecure-zenoh")
        assert "tcp/0.0.0.0" in done.stderr or "tcp/192.0.2.1" in done.stderr
    with socket.socket() as s:  # it never listened
        assert s.connect_ex(("127.0.0.1", port)) != 0


def test_insecure_zenoh_starts_and_warns_and_loopback_starts_quietly(small_tree_015, tmp_path):
    """``--insecure-zenoh`` opens the exposed session, with the warning (every minute, the
    first at once); loopback endpoints only open as before, without it."""
    from thinkfast.sim.realtime import start_daemon

    for extra, warned in (
        (("--zenoh-listen", "tcp/0.0.0.0:{exposed}", "--insecure-zenoh"), True),
        ((), False),
    ):
        port, exposed = free_tcp_port(), free_tcp_port()
        proc = start_daemon(small_tree_015, "tree", free_port(), port, "thinkfast", None, None,
                            tuple(a.format(exposed=exposed) for a in extra))  # fmt: skip
        try:
            assert daemon_says(proc, "serving EGM on", START), daemon_log(proc)
            line = daemon_says(proc, "--insecure-zenoh: the zenoh session is open", 5.0)
        finally:
            code = stop_daemon(proc, timeout=20.0)
        log = daemon_log(proc)
        assert code == 0, log
        if warned:
            assert line is not None and f"tcp/0.0.0.0:{exposed}" in line, log
            assert "WARNING" in line or "warning" in line.lower(), line
        else:
            assert line is None and "insecure" not in log, log


def test_without_access_control_the_sender_check_holds_alone_and_is_refused_unless_insecure(
    cells, tmp_path, caplog
):
    """The daemon's zenoh edge on a TLS session whose access control is off: refused without
    ``--insecure-zenoh`` (the sender check alone trusts a source the sender writes); with it, a
    warning, and the viewer's attributed detections reach the check and are refused as
    ``not_a_camera`` while the camera's are admitted."""
    from thinkfast.daemon.zenoh_edge import ZenohIO
    from thinkfast.errors import ConfigError

    cell, _, _ = cells
    port = free_tcp_port()
    conf = json.loads((cell / "daemon.json5").read_text().split("\n", 2)[2])  # after 2 comments
    conf["access_control"] = {"enabled": False}
    conf["listen"] = {"endpoints": [f"tls/127.0.0.1:{port}"]}
    path = tmp_path / "daemon-no-acl.json5"
    path.write_text(json.dumps(conf))
    with pytest.raises(ConfigError, match="without access control.*--insecure-zenoh"):
        ZenohIO(session_config(config_file=path), "thinkfast")
    with caplog.at_level("WARNING", logger="thinkfast.zenoh"):
        io = ZenohIO(session_config(config_file=path), "thinkfast", insecure=True)
    sessions = []
    got: list[bytes] = []
    try:
        assert "mutual TLS without access control" in caplog.text
        ep = [f"tls/127.0.0.1:{port}"]
        viewer = _node(cell, "viewer-status", False, connect=ep)
        cam = _node(cell, "camera-base", connect=ep)
        sessions += [viewer, cam]
        senders = {"viewer": Thrower(viewer), "camera": Thrower(cam)}
        assert until(lambda: all(t.pub.matching_status.matching for t in senders.values()), 20.0)
        for who, t in senders.items():
            for i in range(20):
                det = {"stamp": time.time(), "position": [5.0, 0.1, 1.0], "frame": "camera",
                       "seq": i, "who": who}  # fmt: skip
                t.publish(json.dumps(det).encode())

        def drained() -> bool:
            got.extend(io.drain())
            return len(got) + io.gate.rejected["not_a_camera"] >= 40

        assert until(drained, 20.0, poll=0.05), (len(got), io.gate.as_dict())
    finally:
        for s in sessions:
            close_session(s)
        io.close()
    assert len(got) == 20 and all(json.loads(p)["who"] == "camera" for p in got)
    gate = io.gate.as_dict()
    assert gate["rejected"] == {"not_a_camera": 20} and gate["rejected_from"] == {
        "viewer-status": 20
    }
