"""A controller link other than EGM drives the real daemon loop: an in-memory controller that
speaks JSON (tests/toy_link.py), one registration, a throw over real zenoh, blocked."""

from __future__ import annotations

import signal
import socket
import threading
import time

import numpy as np
import pytest
import zenoh

from tests.daemon_harness import ballistic_throw, publish_throw, until
from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer, session_config
from thinkfast.control.config import RunConfig
from thinkfast.daemon.options import Endpoints
from thinkfast.daemon.service import Daemon
from thinkfast.link import registry
from thinkfast.sim.judge import judge
from thinkfast.sim.throws import ThrowConfig, make_throw
from thinkfast.tree.file import load_tree


class _Sender:
    """What publish_throw needs: ``publish(payload)`` onto the daemon's detection key."""

    def __init__(self, pub):
        self.pub = pub

    def publish(self, payload: bytes) -> None:
        self.pub.put(payload)


@pytest.mark.realtime
def test_a_toy_controller_link_drives_the_daemon_through_a_blocked_throw(
    small_tree_015, robot, kin, monkeypatch
):
    """The daemon's own loop (Daemon.run) serves a controller that is not EGM: the link is one
    module (tests/toy_link.py) and one registry call; a throw aimed 0.3 m from home is seen
    over zenoh, the arm the toy controller moves blocks it and comes home, every motion within
    the limits on the controller's clock."""
    from tests.toy_link import toy_pair

    controller, factory = toy_pair(robot.home)
    monkeypatch.setitem(registry.LINKS, "toy", factory)  # the one registration (undone after)
    monkeypatch.setattr(signal, "signal", lambda *a: None)  # the loop runs on a thread here
    zport = free_tcp_port()
    conf = session_config(listen=[f"tcp/127.0.0.1:{zport}"], multicast=False)
    daemon = Daemon(load_tree(small_tree_015), robot, RunConfig(), "tree", Endpoints(link="toy"),
                    conf)  # fmt: skip
    loop = threading.Thread(target=daemon.run, daemon=True)
    session = open_peer(connect=[f"tcp/127.0.0.1:{zport}"])
    try:
        loop.start()
        controller.start()
        pub = session.declare_publisher(
            keys.detections("thinkfast"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        assert until(lambda: pub.matching_status.matching and controller.replies > 50, 60.0, 0.01)
        aim, flight, release = (0.25, 1.25), 0.8, (7.8, -0.2, 1.5)
        t_release = time.time() + 0.8
        _, _, at = ballistic_throw(aim, flight, t_release, release)
        publish_throw(_Sender(pub), at, t_release, flight)
        assert until(lambda: daemon.control.state().throws == 1 and not daemon.control.busy,
                     30.0, 0.02), daemon.status(time.time())  # fmt: skip
        status = daemon.status(time.time())
    finally:
        daemon.stop_reason = "SIGTERM"
        loop.join(15.0)
        controller.stop.set()
        controller.join(2.0)
        session.close()
    assert not loop.is_alive()
    assert status["controller"]["enabled"] and status["egm"]["replied"] > 100
    t = np.array([h[0] for h in controller.history])
    q = np.array([h[1] for h in controller.history])
    throw = make_throw(ThrowConfig(drag_coefficient=0.0), np.array(release), aim, flight, 0.0)
    verdict = judge(throw, t, q, kin, 0.8, 0.0335, t_release_wall=t_release)
    assert verdict.blocked, verdict
    assert np.abs(q - robot.home).max() > 0.05  # it moved to block
    assert np.allclose(q[-1], robot.home, atol=2e-3)  # and came home
    qd = np.diff(q, axis=0) / 0.004  # over the controller's cycles
    assert np.all(np.abs(qd) <= robot.v_max + 1e-6)
    assert np.all(q >= robot.q_lower) and np.all(q <= robot.q_upper)


def test_a_link_not_registered_is_refused_naming_the_links_there_are():
    """``--link`` of a name the registry does not know: a ConfigError listing the links."""
    from thinkfast.errors import ConfigError

    with pytest.raises(ConfigError, match="no controller link 'nope'; links: egm"):
        registry.open_link("nope", registry.LinkSpec(), lambda fb, before: None)


def test_the_egm_link_hands_the_core_neutral_feedback():
    """An EgmRobot over real UDP reaches the reply function as the core's Feedback: EGM's
    stamp and sequence number as the controller's clock and cycle, its states as readiness."""
    from thinkfast.contract.egm import encode_robot
    from thinkfast.control.link import Feedback

    seen = []

    def reply(fb, before):
        seen.append(fb)
        return np.zeros(6), np.zeros(6)

    link = registry.open_link("egm", registry.LinkSpec("127.0.0.1:0"), reply)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(encode_robot(7, 28, np.full(6, 0.1)), link.address)
            assert until(lambda: link.poll() > 0, 5.0, 0.005)
    finally:
        link.close()
    (fb,) = seen
    assert isinstance(fb, Feedback) and (fb.t_ms, fb.cycle, fb.ready) == (28, 7, True)
    np.testing.assert_allclose(fb.q, 0.1)
    assert dict(fb.state) == {"motors_on": True, "mci_running": True, "rapid_running": True}
