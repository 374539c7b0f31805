"""The simulators' watch on a daemon (thinkfast/sim/watchdog.py): ready on conditions, each
missing one named; gone after a silence. Real zenoh sessions on loopback; the EGM side is the
controller runner's reply count."""

from __future__ import annotations

import json
import time
from types import SimpleNamespace

import pytest

from thinkfast.contract import keys
from thinkfast.sim.controller_runner import ExchangeStats
from thinkfast.sim.watchdog import READY_REPLIES, DaemonGone, Watchdog


def test_not_ready_names_what_is_missing(sessions):
    _, sim = sessions
    runner = SimpleNamespace(stats=ExchangeStats(answered=0))
    dog = Watchdog(runner, sim, "wd", ("127.0.0.1", 6510), silence=3.0)
    with pytest.raises(DaemonGone) as exc:
        dog.wait_ready(lambda: False, timeout=0.3)
    text = str(exc.value)
    assert "127.0.0.1:6510" in text
    for missing in (f"{READY_REPLIES} EGM replies", "status heard", "subscriber of the detections"):
        assert missing in text


def test_ready_once_replies_status_and_routes_are_there(sessions):
    daemon, sim = sessions
    runner = SimpleNamespace(stats=ExchangeStats(answered=READY_REPLIES))
    dog = Watchdog(runner, sim, "wd", ("127.0.0.1", 6510), silence=3.0)
    det = daemon.declare_subscriber(keys.detections("wd"), lambda s: None)
    pub = sim.declare_publisher(keys.detections("wd"))
    status = daemon.declare_publisher(keys.status("wd"))
    deadline = time.time() + 30  # the daemon's 20 statuses a second, until heard
    while not dog.heard and time.time() < deadline:
        status.put(json.dumps({"state": "idle"}))
        time.sleep(0.05)
    dog.wait_ready(lambda: pub.matching_status.matching, timeout=30.0)  # returns: ready
    det.undeclare()
    with pytest.raises(DaemonGone, match="subscriber of the detections"):
        deadline = time.time() + 30
        while pub.matching_status.matching and time.time() < deadline:
            time.sleep(0.05)  # the undeclared subscriber's route goes
        dog.wait_ready(lambda: pub.matching_status.matching, timeout=0.2)


def test_a_silent_daemon_is_gone(sessions):
    runner = SimpleNamespace(stats=ExchangeStats(answered=5))
    dog = Watchdog(runner, sessions[1], "wd", ("127.0.0.1", 6510), silence=0.1)
    dog.check(0, 3)  # replies changed: fine so far
    time.sleep(0.25)
    with pytest.raises(DaemonGone, match=r"no EGM reply for .* no status for .* after 1 of 3"):
        dog.check(1, 3)


def test_a_daemon_heard_then_silent_is_gone_while_waiting_to_be_ready(sessions):
    daemon, sim = sessions
    runner = SimpleNamespace(stats=ExchangeStats(answered=3))  # answered, then silent
    dog = Watchdog(runner, sim, "wd", ("127.0.0.1", 6510), silence=0.3)
    status = daemon.declare_publisher(keys.status("wd"))
    deadline = time.time() + 30
    while not dog.heard and time.time() < deadline:
        status.put(json.dumps({"state": "idle"}))
        time.sleep(0.05)
    with pytest.raises(DaemonGone, match=r"stopped \(no .* after 0 of 4 throws"):
        dog.wait_ready(lambda: True, timeout=30.0, total=4)  # long before the timeout
