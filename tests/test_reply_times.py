"""Reply timing: ring-buffer percentiles, all-time maxima, and the EGM server feeding them."""

from __future__ import annotations

import math
import socket
import sys

import numpy as np
import pytest

from thinkfast.contract.egm import encode_robot
from thinkfast.link.egm_server import EgmServer
from thinkfast.link.reply_times import ReplyTimes


def test_nothing_timed_yet_summarises_to_none():
    s = ReplyTimes(8).summary()
    assert s == {"n": 0, "late": 0, "wait_us": None, "work_us": None}


def test_percentiles_cover_the_recent_window_and_maxima_all_time():
    r = ReplyTimes(100)
    r.add(1e-3, 5e-3)  # an early outlier, pushed out of the window below
    for k in range(200):
        r.add(1e-6 * (k % 100), 2e-6 * (k % 100))
    s = r.summary()
    assert s["n"] == 201
    assert s["work_us"]["max"] == pytest.approx(198.0)  # the window holds 0..198 us
    assert s["work_us"]["max_all"] == pytest.approx(5000.0)
    assert s["wait_us"]["max_all"] == pytest.approx(1000.0)
    assert s["work_us"]["p50"] == pytest.approx(np.percentile(2.0 * np.arange(100), 50), abs=0.1)


def test_unknown_waits_are_left_out_not_counted_as_zero():
    r = ReplyTimes(10)
    for _ in range(5):
        r.add(math.nan, 1e-4)
    s = r.summary()
    assert s["wait_us"] is None and s["work_us"]["p99"] == pytest.approx(100.0)


def test_a_timing_egm_server_times_every_reply():
    with (
        EgmServer(
            "127.0.0.1:0", lambda fb, before=None: (fb.q_rad, np.zeros(6)), timing=True
        ) as server,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client,
    ):
        client.settimeout(1.0)
        for k in range(1, 21):
            client.sendto(encode_robot(k, k, np.zeros(6)), server.address)
            while not server.poll():
                pass
            client.recv(1024)
        s = server.timing.summary()
    assert s["n"] == 20 and 0.0 < s["work_us"]["p50"] < 1e5
    if sys.platform == "linux":  # kernel arrival stamps: the wait is known
        assert 0.0 <= s["wait_us"]["p50"] < 1e6


def test_a_reply_leaving_more_than_a_cycle_after_its_request_arrived_is_counted_late():
    t = ReplyTimes(size=4, late_after=0.004)
    t.add(0.001, 0.0005)  # 1.5 ms: in time
    t.add(0.0035, 0.0008)  # waited in the socket, then worked: 4.3 ms
    t.add(math.nan, 0.0045)  # no arrival stamp: the work alone is late
    t.add(math.nan, 0.002)
    s = t.summary()
    assert s["late"] == 2 and s["n"] == 4
    assert s["work_us"]["max"] == 4500.0 and s["wait_us"]["max"] == 3500.0


def test_without_a_cycle_nothing_is_counted_late():
    t = ReplyTimes(size=2)
    t.add(0.5, 0.5)
    assert t.summary()["late"] == 0
