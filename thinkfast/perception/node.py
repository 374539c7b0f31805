"""The zenoh edge of ``thinkfast-detect``: frames (and boxes) in, detections and status out.

Frames arrive on ``<prefix>/camera/frame`` into a ring of :data:`FRAME_RING` (a detector that
falls behind works on the newest frames; the frames it never saw show as ``skipped`` seq gaps),
boxes on ``<prefix>/camera/boxes`` into a FIFO. The loop drains both with ``try_recv`` (nothing
runs in a zenoh callback), decodes and detects, and publishes one contract detection per found
ball on ``<prefix>/detections``, stamped with the frame's capture stamp. Every frame is counted
once: rejected by reason (malformed), missed by reason, or detected (a frame on which the
detector itself failed, a bug, is counted in ``errors`` and dropped). A status object goes out
on ``<prefix>/detector/status`` at ``status_rate``.
"""

from __future__ import annotations

import collections
import json
import sys
import time
from typing import Any

import numpy as np
import zenoh

from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import (
    ALONE_AFTER,
    attributed_put,
    close_session,
    drain,
    open_session,
    warn_if_alone,
)
from thinkfast.perception.boxes import (
    BOX_REJECT_REASONS,
    BoxRejection,
    parse_boxes,
    pick_box,
    same_frame,
)
from thinkfast.perception.config import DetectConfig
from thinkfast.perception.detect import MISS_REASONS, Found, detect, detection_payload
from thinkfast.perception.frame import FRAME_REJECT_REASONS, FrameRejection, parse_frame

FRAME_RING = 4  # frames buffered between two drains
BOX_QUEUE = 256
PENDING = 16  # frames held at most while waiting for their boxes


class Counters:
    """Every frame and box payload counted once, by outcome."""

    def __init__(self) -> None:
        self.frames = {
            "received": 0,
            "detected": 0,
            "skipped": 0,
            "errors": 0,
            "rejected": dict.fromkeys(FRAME_REJECT_REASONS, 0),
            "missed": dict.fromkeys((*MISS_REASONS, "no_box"), 0),
        }
        self.boxes = {"received": 0, "matched": 0, "rejected": dict.fromkeys(BOX_REJECT_REASONS, 0)}
        self.published = 0
        self.times: collections.deque[float] = collections.deque(maxlen=1000)

    def as_dict(self) -> dict[str, Any]:
        t = np.array(self.times) * 1e3
        timing = None
        if len(t):
            timing = {
                "p50": round(float(np.median(t)), 3),
                "p99": round(float(np.percentile(t, 99)), 3),
            }
        return {
            "frames": json.loads(json.dumps(self.frames)),
            "boxes": json.loads(json.dumps(self.boxes)),
            "published": self.published,
            "frame_ms": timing,
        }


class DetectorNode:
    """Subscribers, publishers and the per-frame work of ``thinkfast-detect``.

    Args:
        cfg: detector configuration (source, frame, extrinsic, parameters).
        conf: zenoh configuration.
        prefix: key prefix.
        clock: wall clock [s] (box waits and status stamps).
        ros_domain: also publish each detection as a ROS 2 PointStamped on this domain
            (docs/ROS2.md), or None.
    """

    def __init__(
        self,
        cfg: DetectConfig,
        conf: zenoh.Config,
        prefix: str,
        clock=time.time,
        ros_domain: int | None = None,
    ):
        self.cfg, self.clock = cfg, clock
        self.R, self.p = cfg.camera.rotation(), cfg.camera.translation()
        self.counters = Counters()
        self.pending: collections.deque = collections.deque()
        self.recent_boxes: collections.deque = collections.deque(maxlen=64)
        self.last_seq: int | None = None
        self.session = open_session(conf)
        ring = zenoh.handlers.RingChannel(FRAME_RING)
        self.sub_frames = self.session.declare_subscriber(
            keys.camera_frame(prefix, cfg.camera_id or None), ring
        )
        self.sub_boxes = None
        if cfg.source != "colour":
            fifo = zenoh.handlers.FifoChannel(BOX_QUEUE)
            self.sub_boxes = self.session.declare_subscriber(
                keys.camera_boxes(prefix, cfg.camera_id or None), fifo
            )
        self.pub = self.session.declare_publisher(keys.detections(prefix))
        self.put = attributed_put(self.pub)  # its source: a secured daemon checks the sender
        self.pub_status = self.session.declare_publisher(keys.detector_status(prefix))
        self.ros_node = self.ros_pub = None
        if ros_domain is not None:
            from thinkfast.contract import ros, ros_zenoh

            self.ros_node = ros_zenoh.RosNode(self.session, ros_domain, ros.NODE_DETECT)
            self.ros_pub = self.ros_node.publisher(ros.topics(prefix).detections, ros.POINT_STAMPED)
        self.alone = warn_if_alone(
            self.session, f"{prefix}/detections (and no frames arrive)", ALONE_AFTER
        )
        self.next_status = 0.0

    def step(self) -> bool:
        """Take what arrived, work on every frame that is ready; whether anything happened."""
        busy = False
        if self.sub_boxes is not None:
            for payload in drain(self.sub_boxes, BOX_QUEUE):
                busy = True
                self.counters.boxes["received"] += 1
                b = parse_boxes(payload)
                if isinstance(b, BoxRejection):
                    self.counters.boxes["rejected"][b.reason] += 1
                else:
                    self.recent_boxes.append(b)
        for payload in drain(self.sub_frames, FRAME_RING):
            busy = True
            self._receive(payload)
        busy |= self._work()
        now = self.clock()
        if now >= self.next_status:
            self.next_status = now + 1.0 / self.cfg.status_rate
            self.publish_status(now)
        return busy

    def _receive(self, payload: bytes) -> None:
        t0 = time.perf_counter()
        c = self.counters.frames
        c["received"] += 1
        frame = parse_frame(payload, self.cfg.max_frame_bytes)
        if isinstance(frame, FrameRejection):
            c["rejected"][frame.reason] += 1
            return
        if frame.seq is not None:
            if self.last_seq is not None and frame.seq > self.last_seq + 1:
                c["skipped"] += frame.seq - self.last_seq - 1
            self.last_seq = frame.seq
        if self.cfg.source == "colour":
            self._finish(frame, self._detect(frame), t0)
            return
        if len(self.pending) >= PENDING:  # its boxes never came: decide it now
            self._decide(*self.pending.popleft(), force=True)
        self.pending.append((frame, self.clock()))

    def _work(self) -> bool:
        done = False
        while self.pending:
            if not self._decide(*self.pending[0], force=False):
                break
            self.pending.popleft()
            done = True
        return done

    def _decide(self, frame, arrived: float, force: bool) -> bool:
        """Detect in a frame waiting for boxes, if its boxes came or its wait is over."""
        t0 = time.perf_counter()
        boxes = next(
            (b for b in self.recent_boxes if same_frame(b.stamp, b.seq, frame.stamp, frame.seq)),
            None,
        )
        if boxes is not None:
            self.counters.boxes["matched"] += 1
            box = pick_box(boxes, self.cfg.boxes.min_score, self.cfg.boxes.label)
            result = self._detect(frame, box) if box is not None else None
            self._finish(frame, result, t0)
            return True
        if not force and self.clock() - arrived < self.cfg.boxes.wait:
            return False
        if self.cfg.source == "auto":
            self._finish(frame, self._detect(frame), t0)
        else:
            self.counters.frames["missed"]["no_box"] += 1
        return True

    def _detect(self, frame, box=None):
        """:func:`detect`, or False if it raised (counted in ``errors``, logged once): a bug must
        not stop the detector."""
        try:
            return detect(frame, self.cfg, box)
        except Exception as exc:
            if not self.counters.frames["errors"]:
                print(f"thinkfast-detect: detection failed: {exc!r}", file=sys.stderr)
            self.counters.frames["errors"] += 1
            return False

    def _finish(self, frame, result, t0: float) -> None:
        c = self.counters.frames
        if result is False:  # counted in errors
            pass
        elif result is None:  # boxes came, none usable
            c["missed"]["no_ball"] += 1
        elif isinstance(result, Found):
            c["detected"] += 1
            payload = detection_payload(
                result, frame.stamp, frame.seq, self.cfg.frame, self.R, self.p,
                self.cfg.camera_id or None,
            )  # fmt: skip
            self.put(payload)
            if self.ros_pub is not None:
                from thinkfast.contract.ros import point_from_detection

                self.ros_pub.put(point_from_detection(payload))
            self.counters.published += 1
        else:
            c["missed"][result.reason] += 1
        self.counters.times.append(time.perf_counter() - t0)

    def publish_status(self, now: float) -> None:
        status = {"stamp": now, "source": self.cfg.source, **self.counters.as_dict()}
        self.pub_status.put(json.dumps(status).encode())

    def close(self) -> None:
        self.alone.cancel()
        if self.ros_node is not None:
            self.ros_node.close()
        close_session(self.session)
