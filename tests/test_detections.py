"""Detection payloads: the contract of docs/INTERFACES.md, fuzzing, ordering, camera -> base."""

import json
import math

import numpy as np
import pytest

from thinkfast.config import from_dict
from thinkfast.contract.detection import (
    REJECT_REASONS,
    Detection,
    DetectionCounters,
    DetectionLimits,
    Rejection,
    parse_detection,
)
from thinkfast.contract.frames import CameraExtrinsic, rotation_from_rpy, to_base
from thinkfast.control.intake import ORDER_CLASSES, classify_order

COV = [0.01, 0.001, 0.0, 0.001, 0.02, 0.0, 0.0, 0.0, 0.03]


def _payload(**fields) -> bytes:
    base = {"stamp": 1763800000.1234, "position": [6.0, 0.1, 1.2]}
    base.update(fields)
    return json.dumps({k: v for k, v in base.items() if v is not _DROP}).encode()


_DROP = object()


def test_minimal_payload_gets_the_documented_defaults():
    d = parse_detection(_payload())
    assert isinstance(d, Detection)
    assert d.stamp == 1763800000.1234 and d.frame == "camera"
    assert d.confidence is None and d.seq is None and d.covariance is None
    np.testing.assert_array_equal(d.position, [6.0, 0.1, 1.2])
    assert not d.position.flags.writeable


def test_full_payload_round_trips():
    d = parse_detection(
        _payload(frame="base", confidence=0.93, seq=17, covariance=COV, extra={"x": 1})
    )
    assert (d.frame, d.confidence, d.seq) == ("base", 0.93, 17)
    np.testing.assert_array_equal(d.covariance, np.reshape(COV, (3, 3)))


def test_null_optional_fields_count_as_absent():
    d = parse_detection(_payload(frame=None, confidence=None, seq=None, covariance=None))
    assert isinstance(d, Detection) and d.frame == "camera"


@pytest.mark.parametrize(
    "payload, reason",
    [
        ("not bytes", "not_bytes"),
        (None, "not_bytes"),
        (b"x" * 5000, "too_large"),
        (b"\xff\xfe{}", "not_utf8"),
        (b"{", "not_json"),
        (b"[" * 3000 + b"]" * 3000, "too_large"),
        (b"[" * 2000 + b"]" * 2000, "not_json"),  # nesting deeper than the parser allows
        (b"[1, 2]", "not_object"),
        (b"3.5", "not_object"),
        (_payload(stamp=_DROP), "missing_stamp"),
        (_payload(stamp=None), "missing_stamp"),
        (_payload(stamp="now"), "bad_stamp"),
        (_payload(stamp=True), "bad_stamp"),
        (_payload(stamp=-1.0), "bad_stamp"),
        (b'{"stamp": NaN, "position": [1, 2, 3]}', "bad_stamp"),
        (b'{"stamp": Infinity, "position": [1, 2, 3]}', "bad_stamp"),
        (b'{"stamp": 1e999, "position": [1, 2, 3]}', "bad_stamp"),
        (b'{"stamp": 1' + b"0" * 400 + b', "position": [1, 2, 3]}', "bad_stamp"),
        (_payload(position=_DROP), "missing_position"),
        (_payload(position=[1, 2]), "bad_position"),
        (_payload(position=[1, 2, 3, 4]), "bad_position"),
        (_payload(position=[1, True, 3]), "bad_position"),
        (_payload(position=[1, "2", 3]), "bad_position"),
        (_payload(position={"x": 1}), "bad_position"),
        (_payload(position=[1, 2, 1e6]), "bad_position"),
        (b'{"stamp": 1, "position": [1, -Infinity, 3]}', "bad_position"),
        (_payload(frame="world"), "bad_frame"),
        (_payload(frame=["camera"]), "bad_frame"),
        (_payload(frame=1), "bad_frame"),
        (_payload(confidence=1.5), "bad_confidence"),
        (_payload(confidence=-0.1), "bad_confidence"),
        (_payload(confidence=True), "bad_confidence"),
        (_payload(confidence="high"), "bad_confidence"),
        (_payload(seq=1.0), "bad_seq"),
        (_payload(seq=-1), "bad_seq"),
        (_payload(seq=2**63), "bad_seq"),
        (_payload(seq=False), "bad_seq"),
        (_payload(seq="17"), "bad_seq"),
        (_payload(covariance=COV[:8]), "bad_covariance"),
        (_payload(covariance=[1, 2, 3, 4, 5, 6, 7, 8, 9]), "bad_covariance"),  # asymmetric
        (_payload(covariance=[-1, 0, 0, 0, 1, 0, 0, 0, 1]), "bad_covariance"),
        (_payload(covariance=[1, 2, 0, 2, 1, 0, 0, 0, 1]), "bad_covariance"),  # not PSD
        (_payload(covariance=[1e300, 0, 0, 0, 1, 0, 0, 0, 1]), "bad_covariance"),
        (_payload(covariance=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "bad_covariance"),
    ],
)
def test_each_contract_violation_is_rejected_with_its_reason(payload, reason):
    r = parse_detection(payload)
    assert isinstance(r, Rejection) and r.reason == reason, r
    assert r.reason in REJECT_REASONS


def _garbage(rng, depth=0):
    pick = int(rng.integers(10 if depth < 3 else 7))
    simple = [
        None,
        True,
        float(rng.normal() * 10.0 ** int(rng.integers(-5, 308))),
        int(rng.integers(-(2**62), 2**62)) * int(rng.integers(1, 10**6)),
        "x" * int(rng.integers(0, 20)),
        float("nan"),
        float(rng.choice([math.inf, -math.inf])),
    ]
    if pick < 7:
        return simple[pick]
    if pick == 7:
        return [_garbage(rng, depth + 1) for _ in range(int(rng.integers(0, 5)))]
    if pick == 8:
        return {str(rng.integers(5)): _garbage(rng, depth + 1) for _ in range(int(rng.integers(3)))}
    return [float(x) for x in rng.uniform(-50, 50, int(rng.integers(2, 5)))]


def _fuzz_payload(rng):
    """Returns (payload bytes, expected Detection fields or None when it may be invalid)."""
    kind = int(rng.integers(5))
    if kind == 0:
        return rng.bytes(int(rng.integers(0, 300))), None
    if kind == 1:
        return json.dumps(_garbage(rng)).encode(), None
    keys = ["stamp", "position", "frame", "confidence", "seq", "covariance"]
    if kind == 2:  # right keys, garbage values
        obj = {k: _garbage(rng) for k in keys if rng.integers(3)}
        return json.dumps(obj).encode(), None
    if kind == 3:  # a valid payload with bytes damaged
        b = bytearray(_payload(seq=3))
        for _ in range(int(rng.integers(1, 4))):
            b[int(rng.integers(len(b)))] = int(rng.integers(256))
        return bytes(b), None
    fields = {
        "stamp": float(rng.uniform(0, 2e9)),
        "position": [float(x) for x in rng.uniform(-20, 20, 3)],
        "frame": str(rng.choice(["camera", "base"])),
        "confidence": float(rng.uniform(0, 1)),
        "seq": int(rng.integers(0, 2**40)),
    }
    a = rng.normal(size=(3, 3)) * 0.1
    fields["covariance"] = [float(x) for x in (a @ a.T).ravel()]
    return json.dumps(fields).encode(), fields


def test_ten_thousand_fuzzed_payloads_are_each_counted_and_none_raises():
    rng = np.random.default_rng(4)
    counters = DetectionCounters()
    n_valid = 0
    for _ in range(10_000):
        payload, expected = _fuzz_payload(rng)
        result = parse_detection(payload)
        counters.count(result)
        if expected is not None:
            n_valid += 1
            assert isinstance(result, Detection), result
            assert result.stamp == expected["stamp"] and result.seq == expected["seq"]
            assert result.position.tolist() == expected["position"]
            assert result.covariance.ravel().tolist() == expected["covariance"]
        elif isinstance(result, Detection):
            assert np.isfinite(result.position).all() and math.isfinite(result.stamp)
    assert counters.total == 10_000
    assert counters.accepted >= n_valid > 1500
    assert sum(counters.rejected.values()) > 5000
    assert set(counters.as_dict()["rejected"]) == set(REJECT_REASONS)


@pytest.mark.parametrize(
    "args, expected",
    [
        ((1.0, None, None, None), "new"),
        ((2.0, 5, 1.0, 9), "new"),  # stamps decide: a sender restart resets seq
        ((1.0, 3, 1.0, 3), "duplicate"),
        ((1.0, None, 1.0, 3), "duplicate"),
        ((1.0, 4, 1.0, 3), "new"),
        ((1.0, 2, 1.0, 3), "out_of_order"),
        ((0.5, 9, 1.0, 3), "out_of_order"),
    ],
)
def test_classify_order(args, expected):
    assert classify_order(*args) == expected in ORDER_CLASSES


def test_classify_order_refuses_stamps_far_from_the_receiver_clock():
    lim = DetectionLimits(max_age=1.0, max_future=0.25)
    assert classify_order(98.5, None, None, None, now=100.0, limits=lim) == "stale"
    assert classify_order(100.5, None, None, None, now=100.0, limits=lim) == "future"
    assert classify_order(1e300, None, None, None, now=100.0, limits=lim) == "future"
    assert classify_order(99.9, None, 99.8, None, now=100.0, limits=lim) == "new"


def test_rotation_from_rpy_is_a_proper_rotation_with_urdf_convention():
    np.testing.assert_allclose(
        rotation_from_rpy((0, 0, math.pi / 2)) @ [1, 0, 0], [0, 1, 0], atol=1e-15
    )
    np.testing.assert_allclose(
        rotation_from_rpy((0, math.pi / 2, 0)) @ [1, 0, 0], [0, 0, -1], atol=1e-15
    )
    np.testing.assert_allclose(
        rotation_from_rpy((math.pi / 2, 0, 0)) @ [0, 1, 0], [0, 0, 1], atol=1e-15
    )
    rng = np.random.default_rng(5)
    for rpy in rng.uniform(-3, 3, (50, 3)):
        R = rotation_from_rpy(rpy)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0)


def test_to_base_moves_position_and_rotates_covariance():
    ext = CameraExtrinsic(xyz=(0.1, -0.8, 1.0), rpy=(0.0, 0.0, math.pi / 2))
    d = parse_detection(_payload(position=[2.0, 0.0, 0.5], covariance=COV))
    b = to_base(d, ext.rotation(), ext.translation())
    assert b.frame == "base" and b.stamp == d.stamp
    np.testing.assert_allclose(b.position, [0.1, 1.2, 1.5], atol=1e-12)
    np.testing.assert_allclose(np.diag(b.covariance), [0.02, 0.01, 0.03], atol=1e-15)
    already = parse_detection(_payload(frame="base"))
    assert to_base(already, ext.rotation(), ext.translation()) is already


def test_default_extrinsic_looks_along_base_x_and_loads_from_toml_tables():
    ext = CameraExtrinsic()
    np.testing.assert_array_equal(ext.rotation(), np.eye(3))
    loaded = from_dict(CameraExtrinsic, {"xyz": [0.46, 0.0, 0.30]}, "run.toml", "camera")
    assert loaded == ext
