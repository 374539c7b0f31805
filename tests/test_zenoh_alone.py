"""No zenoh peer reachable: the daemon's and detector's sessions and replay say so, once."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest
import zenoh

from tests.conftest import run_cli
from thinkfast.contract.zenoh_session import (
    free_tcp_port,
    neighbours,
    session_config,
    warn_if_alone,
)

GOLDEN_RECORD = Path(__file__).parent / "data" / "record_v1_golden.h5"


def _wait_for(cond, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "thinkfast.zenoh"]


@pytest.mark.realtime
def test_a_session_without_peers_is_warned_once(caplog):
    caplog.set_level(logging.WARNING, logger="thinkfast.zenoh")
    session = zenoh.open(session_config(multicast=False))  # no endpoints, no scouting: alone
    try:
        timer = warn_if_alone(session, "x/status", after=0.2)
        timer.join(2.0)
        assert neighbours(session) == 0
        (msg,) = _warnings(caplog)
        assert "no zenoh peer or router" in msg and "x/status" in msg and "--zenoh-connect" in msg
    finally:
        session.close()


@pytest.mark.realtime
def test_a_connected_session_is_not_warned(caplog):
    caplog.set_level(logging.WARNING, logger="thinkfast.zenoh")
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    a = zenoh.open(session_config(listen=[ep], multicast=False))
    b = zenoh.open(session_config(connect=[ep], multicast=False))
    try:
        assert _wait_for(lambda: neighbours(a) == 1 and neighbours(b) == 1)
        warn_if_alone(a, "x/status", after=0.1).join(2.0)
        warn_if_alone(b, "x/status", after=0.1).join(2.0)
        assert _warnings(caplog) == []
    finally:
        b.close()
        a.close()


@pytest.mark.realtime
def test_replay_to_no_one_warns_and_to_a_subscriber_does_not():
    proc = run_cli("thinkfast-sim", "replay", str(GOLDEN_RECORD), "--speed", "50", timeout=120)
    assert proc.returncode == 0 and proc.stdout.startswith("replayed ")
    assert "warning: no subscriber of thinkfast/detections" in proc.stderr

    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    listener = zenoh.open(session_config(listen=[ep], multicast=False))
    got = []
    sub = listener.declare_subscriber("thinkfast/detections", lambda s: got.append(s))
    try:
        proc = run_cli(
            "thinkfast-sim", "replay", str(GOLDEN_RECORD), "--speed", "50",
            "--zenoh-connect", ep, timeout=120,
        )  # fmt: skip
    finally:
        sub.undeclare()
        listener.close()
    assert proc.returncode == 0, proc.stderr
    assert "warning" not in proc.stderr
    n = int(proc.stdout.split()[1])
    assert n > 0 and len(got) == n
