"""Reply timing: percentiles over a ring, and replies counted late against the cycle."""

import math

from thinkfast.daemon.reply_times import ReplyTimes


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
