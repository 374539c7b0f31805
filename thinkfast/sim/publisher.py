"""Publish simulated detections over zenoh in real time.

The thin edge between :mod:`thinkfast.sim.camera` and the daemon: each detection's payload
(:func:`~thinkfast.sim.camera.detection_payload`) goes out on ``<prefix>/detections`` at its
delivery time. The schedule is absolute (target wall times, never accumulated sleeps), so a late
wake-up delays one sample and never the ones after it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from typing import NamedTuple

import zenoh

from thinkfast.contract.zenoh_session import attributed_put
from thinkfast.sim.camera import SimDetection, detection_payload


class PublishReport(NamedTuple):
    """What :func:`publish_detections` did: samples sent, and their lateness [s] (max, mean)."""

    sent: int
    max_late: float
    mean_late: float


def publish_detections(
    session: zenoh.Session, key: str, detections: Iterable[SimDetection], **schedule
) -> PublishReport:
    """Publish each detection on ``key`` at ``t0_wall + delivery_time`` with stamp
    ``t0_wall + capture_stamp``: :func:`send_detections` (``schedule``: its keyword arguments,
    ``t0_wall``, ``clock``, ``sleep``, ``with_covariance``, ``stop``) through a publisher of
    ``session`` (an open zenoh session; ``key`` normally
    :func:`thinkfast.contract.keys.detections`)."""
    publisher = session.declare_publisher(key)
    try:
        return send_detections(attributed_put(publisher), detections, **schedule)
    finally:
        publisher.undeclare()


def send_detections(
    put: Callable[[bytes], object],
    detections: Iterable[SimDetection],
    t0_wall: float = 0.0,
    clock: Callable[[], float] = time.time,
    sleep: Callable[[float], None] = time.sleep,
    with_covariance: bool = False,
    stop: threading.Event | None = None,
) -> PublishReport:
    """Hand each detection's payload to ``put`` at ``t0_wall + delivery_time`` with stamp
    ``t0_wall + capture_stamp``: the one real-time detection schedule (the lockstep simulator
    delivers the same detections on simulated time).

    Detections made with ``t_release_wall`` set to a real wall time go out with ``t0_wall = 0``;
    detections made on a clock starting at 0 (``t_release_wall = 0``, e.g. a precomputed throw
    set) are shifted to now with ``t0_wall = clock() + margin``. Samples are sent in delivery
    order; one already due is sent at once.

    Args:
        put: sends one payload (a zenoh publisher's ``put``, or another sender's, e.g. a ROS 2
            one).
        detections: what to send.
        t0_wall: offset added to delivery times and stamps [s].
        clock: wall clock [s] (same clock as the stamps).
        sleep: sleeps the given seconds (injectable for tests).
        with_covariance: add the noise model's covariance to each payload.
        stop: if set, return early (checked before each sample).
    """
    pending = sorted(detections, key=lambda d: d.delivery_time)
    late = []
    for sd in pending:
        if stop is not None and stop.is_set():
            break
        due = t0_wall + sd.delivery_time
        wait = due - clock()
        if wait > 0.0:
            sleep(wait)
        shifted = sd._replace(capture_stamp=sd.capture_stamp + t0_wall)
        put(detection_payload(shifted, with_covariance))
        late.append(max(0.0, clock() - due))
    if not late:
        return PublishReport(0, 0.0, 0.0)
    return PublishReport(len(late), max(late), sum(late) / len(late))
