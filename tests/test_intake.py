"""Detection intake against spurious future stamps: one must not blind the order watermark.

A genuine detection is stamped at capture and received at least the pipeline latency later, so
with synchronised clocks its stamp is never later than the receive time plus the clock offset.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from thinkfast.contract.detection import DetectionLimits
from thinkfast.contract.frames import CameraExtrinsic
from thinkfast.control.intake import Intake, classify_order

RATE = 50.0  # Hz, the camera's frame rate
LATENCY = (0.030, 0.060)  # s, capture-to-receive, uniform per frame (the simulated camera's)
T0 = 1_763_800_000.0  # s, wall clock of the first capture
N = 70  # genuine detections: 1.4 s of a throw at 50 Hz


def _payload(stamp: float, seq: int | None, x: float = 6.0) -> bytes:
    return json.dumps({"stamp": stamp, "seq": seq, "position": [x, 0.1, 1.2]}).encode()


def _genuine(seed: int) -> list[tuple[float, float, int]]:
    """(receive time, stamp, seq) of a 50 Hz stream delivered in order (FIFO)."""
    rng = np.random.default_rng(seed)
    out, recv = [], -math.inf
    for k in range(N):
        stamp = T0 + k / RATE
        recv = max(stamp + rng.uniform(*LATENCY), recv)
        out.append((recv, stamp, k))
    return out


def _run(events: list[tuple[float, bytes, str]], intake: Intake) -> dict[str, list[str]]:
    """Feed (receive time, payload, tag) in receive order; the tags of what was accepted."""
    taken: dict[str, list[str]] = {"accepted": [], "dropped": []}
    for now, payload, tag in sorted(events, key=lambda e: e[0]):
        got = intake.take(payload, now)
        taken["accepted" if got is not None else "dropped"].append(tag)
        if intake.last_stamp is not None:  # the watermark never runs ahead of the clock
            assert intake.last_stamp <= now + intake.limits.max_future
    return taken


def _with_spurious(seed: int, ahead: float, after: int = 3) -> tuple[list, float, float]:
    """The genuine stream plus one detection received 1 ms after genuine #``after``, stamped
    ``ahead`` [s] later than its receive time (a wrong clock or a bogus sender), with no seq."""
    genuine = _genuine(seed)
    events = [(r, _payload(s, k), f"g{k}") for r, s, k in genuine]
    recv = genuine[after][0] + 0.001
    events.append((recv, json.dumps({"stamp": recv + ahead, "position": [1, 2, 3]}).encode(), "s"))
    return events, recv, recv + ahead


@pytest.mark.parametrize("ahead", [0.05, 0.2, 1.0, 10.0])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_one_far_future_detection_is_dropped_and_every_genuine_one_is_accepted(seed, ahead):
    """A detection stamped 0.05 s, 0.2 s, 1 s or 10 s ahead of its receive time is counted
    ``future`` and leaves the watermark alone: all 70 genuine detections of the throw get in."""
    events, _, _ = _with_spurious(seed, ahead)
    intake = Intake(CameraExtrinsic(), DetectionLimits())
    taken = _run(events, intake)
    assert taken["dropped"] == ["s"]
    assert taken["accepted"] == [f"g{k}" for k in range(N)]
    assert intake.order == {"duplicate": 0, "out_of_order": 0, "stale": 0, "future": 1}
    assert intake.last_stamp == T0 + (N - 1) / RATE


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_future_stamp_within_the_allowance_costs_only_the_detections_in_flight(seed):
    """Accepted at the allowance's edge (receive time + max_future), the spurious detection
    drops exactly the genuine ones captured before its stamp and received after it: at most
    (largest latency + max_future) * rate of them, i.e. 4 at 50 Hz with 60 ms latency."""
    limits = DetectionLimits()
    events, recv, stamp = _with_spurious(seed, limits.max_future)
    intake = Intake(CameraExtrinsic(), limits)
    taken = _run(events, intake)
    lost = {f"g{k}" for r, s, k in _genuine(seed) if s < stamp and r > recv}
    assert set(taken["dropped"]) == lost and "s" in taken["accepted"]
    assert intake.order["out_of_order"] == len(lost)
    assert 1 <= len(lost) <= math.ceil((LATENCY[1] + limits.max_future) * RATE)
    later = [f"g{k}" for r, s, k in _genuine(seed) if r > recv and f"g{k}" not in lost]
    assert later and set(later) <= set(taken["accepted"])


def test_a_burst_of_future_stamps_within_the_allowance_cannot_blind_the_intake():
    """40 detections 1 ms apart, each stamped max_future after its receive time, hold the
    watermark at most max_future ahead of the clock: every genuine detection captured after
    the burst's last stamp is accepted."""
    limits = DetectionLimits()
    genuine = _genuine(7)
    events = [(r, _payload(s, k), f"g{k}") for r, s, k in genuine]
    burst = [genuine[5][0] + 0.001 * (i + 1) for i in range(40)]
    events += [
        (r, json.dumps({"stamp": r + limits.max_future, "position": [1, 2, 3]}).encode(), "b")
        for r in burst
    ]
    intake = Intake(CameraExtrinsic(), limits)
    taken = _run(events, intake)
    last = burst[-1] + limits.max_future
    after = [f"g{k}" for r, s, k in genuine if s > last]
    assert len(after) > N // 2 and set(after) <= set(taken["accepted"])
    assert taken["accepted"][-1] == f"g{N - 1}"


def test_the_future_limit_is_small_against_a_frame_and_counts_ahead_of_the_receive_time():
    """A stamp up to max_future after the receive time is new; beyond it, future. The limit is
    positive (clock offsets) and under half a frame period at 50 Hz."""
    lim = DetectionLimits()
    assert 0.0 < lim.max_future <= 0.5 / RATE
    now = T0 + 1.0
    assert classify_order(now + lim.max_future, None, None, None, now, lim) == "new"
    assert classify_order(now + lim.max_future + 1e-6, None, None, None, now, lim) == "future"
    assert classify_order(now + 0.2, None, T0, None, now, lim) == "future"


def test_readme_states_the_configured_future_limit():
    """The README's Interfaces bullet names the same limit as DetectionLimits.max_future."""
    from tests.conftest import ROOT

    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    ms = f"{DetectionLimits().max_future * 1e3:g} ms"
    assert f"more than {ms} later than its receive time" in readme


def test_dropped_counts_each_reason_as_the_status_does():
    intake = Intake(CameraExtrinsic(), DetectionLimits())
    ok = json.dumps({"stamp": 10.0, "position": [5.0, 0.0, 1.0]}).encode()
    assert intake.take(ok, None) is not None
    for _ in range(3):
        assert intake.take(b"not json", None) is None
    assert intake.take(ok, None) is None  # the same stamp again
    assert intake.last_drop[0] == "duplicate"
    assert (intake.dropped("not_json"), intake.dropped("duplicate")) == (3, 1)
    counts = intake.as_dict()
    assert counts["rejected"]["not_json"] == 3 and counts["dropped"]["duplicate"] == 1
    assert intake.dropped("stale") == 0
