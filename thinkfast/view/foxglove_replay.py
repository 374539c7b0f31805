"""A flight record played on the Foxglove server at its own pace (``thinkfast-sim replay RECORD
--foxglove [HOST:]PORT``, docs/LIVE_VIEW.md).

The live Foxglove view's server and channels (:class:`~thinkfast.view.foxglove.
FoxgloveSink`, without the status channel: a record keeps none) and its one painter
(:class:`~thinkfast.view.channels.ChannelPainter`), fed the calls the Rerun replay and the
MCAP's scene are drawn from (:func:`~thinkfast.view.replay.timed_calls`: raw and accepted
detections, beliefs, crossings, decisions, the arm and joints at most ``joint_rate`` per second,
events) at the record's pace: the call at record time ``t`` goes out at wall time
``start + (t - t0) / speed`` on an absolute schedule (a late one goes out at once and delays no
other). Log times are the record's, so the scene's messages are byte for byte the MCAP's
(``--scene``). Playing starts ``SETTLE`` after the first client subscribed (a client that opens
later joins mid-way) and ends with the record; the server stops once every client has left (or
at Ctrl-C): stopping it at once would drop what it still queues for a client.

No EGM cycle to protect here, so no per-cycle budget: the daemon's view waits for time between
replies, a replay only for the record's clock. On a slow host messages go out late, none is
dropped by the replay (a client too slow for the SDK's backlog loses its oldest).
"""

from __future__ import annotations

import functools
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from thinkfast.errors import ConfigError

SETTLE = 0.5  # s from the first subscription to the first message: the client's others land


class Played(NamedTuple):
    """What :func:`play` did: calls made, and how late the latest was [s]."""

    calls: int
    max_late: float


def play(
    calls: list,
    painter,
    speed: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Played:
    """Make each (record time [s], method, arguments) call of ``calls`` (time-ordered) on
    ``painter`` at ``start + (t - t0) / speed`` (``start``: now, ``t0``: the first call's time).
    """
    if speed <= 0:
        raise ConfigError("--speed", None, "must be > 0")
    if not calls:
        return Played(0, 0.0)
    start, t0, late = clock(), calls[0][0], 0.0
    for t, name, args in calls:
        due = start + (t - t0) / speed
        wait = due - clock()
        if wait > 0.0:
            sleep(wait)
        else:
            late = max(late, -wait)
        getattr(painter, name)(t, *args)
    return Played(len(calls), late)


def record_to_foxglove(
    record, host: str, port: int, tree: Path | None = None, speed: float = 1.0,
    joint_rate: float = 50.0, report=functools.partial(print, flush=True),
) -> dict[str, int]:  # fmt: skip
    """Serve ``record`` (a :class:`~thinkfast.record.format.Record`) on ``host:port`` and play
    it once a client subscribes (module doc); ``tree`` gives the goal grid and the plane.

    Returns:
        messages sent per topic.

    Raises:
        ConfigError: foxglove-sdk missing, or the record's run configuration does not validate.
        TreeFileError: ``tree`` cannot be read.
    """
    from thinkfast.view.channels import ChannelPainter
    from thinkfast.view.foxglove import FoxgloveSink
    from thinkfast.view.record_rerun import drawing_inputs
    from thinkfast.view.replay import timed_calls

    cfg, robot, px, goal_yz = drawing_inputs(record, tree)
    calls = timed_calls(record, cfg, joint_rate, crossings=px is not None)
    sink = FoxgloveSink(host, port, name=f"thinkfast-sim replay {record.path.name}",
                        status=False, count=True)  # fmt: skip
    subs = sink.subscriptions
    sent: Counter = Counter()

    def emit(t: float, topic: str, data: bytes) -> None:
        sink.emit(t, topic, data)
        sent[topic] += 1

    try:
        painter = ChannelPainter(emit, robot, 0.0 if px is None else px, goal_yz)
        span = calls[-1][0] - calls[0][0] if calls else 0.0
        report(
            f"foxglove on ws://{host}:{sink.port}: {record.path.name} ({span:.1f} s, "
            f"{len(calls)} steps) plays at {speed:g}x once a client subscribes (Ctrl-C ends)"
        )
        while not subs.first.wait(0.2):  # (a bounded wait: Ctrl-C comes through)
            pass
        time.sleep(SETTLE)
        done = play(calls, painter, speed)
        report(
            f"played {sum(sent.values())} messages on {len(sent)} topics (at most "
            f"{done.max_late:.2f} s behind the record's pace); serving until every client has "
            "left (Ctrl-C ends)"
        )
        while subs.open > 0:  # the server stops with them: its queued messages reach them
            time.sleep(0.2)
    finally:
        sink.close()
    return dict(sent)
