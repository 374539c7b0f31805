"""EGM wire format: field numbers of docs/INTERFACES.md, units, round trips, bad data refused."""

import math
import struct

import numpy as np
import pytest

from thinkfast.contract import egm
from thinkfast.errors import ThinkfastError


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b, n = n & 0x7F, n >> 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _len_field(number: int, payload: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def _int_field(number: int, value: int) -> bytes:
    return _varint(number << 3) + _varint(value)


def _joints(values_deg, packed: bool = False) -> bytes:
    """EgmJoints by hand: field 1, repeated double (unpacked as ABB sends, or packed)."""
    if packed:
        return _len_field(1, b"".join(struct.pack("<d", v) for v in values_deg))
    return b"".join(_varint(1 << 3 | 1) + struct.pack("<d", v) for v in values_deg)


def _robot_bytes(seqno=7, tm=1234, deg=(10, -20, 30, -40, 50, -60), packed=False, extra=b""):
    """An EgmRobot from the field numbers of docs/INTERFACES.md, independent of the schema."""
    header = _int_field(1, seqno) + _int_field(2, tm) + _int_field(3, 2)
    feedback = _len_field(1, _joints(deg, packed))
    return (
        _len_field(1, header)
        + _len_field(2, feedback)
        + _len_field(4, _int_field(1, 1))  # motorState: MOTORS_ON
        + _len_field(5, _int_field(1, 3))  # mciState: MCI_RUNNING
        + extra
    )


def test_hand_written_robot_bytes_decode_with_interface_field_numbers():
    fb = egm.decode_robot(_robot_bytes())
    assert (fb.seqno, fb.tm_ms, fb.motors_on, fb.mci_running) == (7, 1234, True, True)
    np.testing.assert_allclose(fb.q_rad, np.radians([10, -20, 30, -40, 50, -60]), rtol=1e-15)


def test_packed_joints_are_accepted_too():
    fb = egm.decode_robot(_robot_bytes(packed=True))
    np.testing.assert_allclose(fb.q_rad, np.radians([10, -20, 30, -40, 50, -60]), rtol=1e-15)


def test_unknown_fields_are_ignored():
    extra = _len_field(12, b"\x0a\x03abc") + _int_field(99, 5) + _len_field(6, b"\x0a\x00")
    fb = egm.decode_robot(_robot_bytes(extra=extra))
    assert fb.seqno == 7


def test_sensor_message_has_the_interface_layout_in_degrees():
    q = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
    data = egm.encode_sensor(5, 99, q, 2 * q)
    msg = egm.EgmSensor.FromString(data)
    assert (msg.header.seqno, msg.header.tm, msg.header.mtype) == (5, 99, egm.MSGTYPE_CORRECTION)
    np.testing.assert_allclose(msg.planned.joints.joints, np.degrees(q), rtol=1e-15)
    np.testing.assert_allclose(msg.speedRef.joints.joints, np.degrees(2 * q), rtol=1e-15)
    # Field numbers from docs/INTERFACES.md: header=1, planned=2, speedRef=3; mtype=3 in the header.
    assert data[0] == (1 << 3 | 2) and data.count(bytes([2 << 3 | 2])) >= 1
    d = egm.EgmSensor.DESCRIPTOR
    assert {f.name: f.number for f in d.fields} == {"header": 1, "planned": 2, "speedRef": 3}
    r = egm.EgmRobot.DESCRIPTOR
    numbers = {f.name: f.number for f in r.fields}
    assert numbers == {
        "header": 1, "feedBack": 2, "planned": 3, "motorState": 4, "mciState": 5,
        "rapidExecState": 8,
    }  # fmt: skip


def test_controller_state_decodes_and_gates_ready():
    q = np.zeros(6)
    fb = egm.decode_robot(egm.encode_robot(1, 2, q))
    assert (fb.motors_on, fb.mci_running, fb.rapid_running, fb.ready) == (True, True, True, True)
    for kw, field in (
        ({"motors_on": False}, "motors_on"),
        ({"mci_running": False}, "mci_running"),
        ({"rapid_running": False}, "rapid_running"),
    ):
        fb = egm.decode_robot(egm.encode_robot(1, 2, q, **kw))
        assert getattr(fb, field) is False and not fb.ready
    fb = egm.decode_robot(egm.encode_robot(1, 2, q, rapid_running=None))
    assert fb.rapid_running is None and fb.ready  # not reported: motors and MCI decide
    bare = egm.EgmRobot()
    bare.header.seqno = 1
    bare.feedBack.joints.joints.extend([0.0] * 6)
    fb = egm.decode_robot(bare.SerializeToString())
    assert not fb.motors_on and not fb.mci_running and not fb.ready  # unknown reads as off


def test_round_trips_are_exact_to_rounding_for_random_values():
    rng = np.random.default_rng(0)
    for _ in range(200):
        q, qd = rng.uniform(-7, 7, 6), rng.uniform(-10, 10, 6)
        seq, tm = int(rng.integers(0, 2**32)), int(rng.integers(0, 2**32))
        s = egm.decode_sensor(egm.encode_sensor(seq, tm, q, qd))
        assert (s.seqno, s.tm_ms, s.mtype) == (seq, tm, egm.MSGTYPE_CORRECTION)
        np.testing.assert_allclose(s.q_rad, q, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(s.qd_rad_s, qd, rtol=1e-14, atol=1e-15)
        on, run = bool(rng.integers(2)), bool(rng.integers(2))
        r = egm.decode_robot(egm.encode_robot(seq, tm, q, motors_on=on, mci_running=run))
        assert (r.seqno, r.tm_ms, r.motors_on, r.mci_running) == (seq, tm, on, run)
        np.testing.assert_allclose(r.q_rad, q, rtol=1e-14, atol=1e-15)


def test_seqno_and_tm_wrap_modulo_2_32():
    s = egm.decode_sensor(egm.encode_sensor(2**32 + 3, 2**32 + 9, np.zeros(6), np.zeros(6)))
    assert (s.seqno, s.tm_ms) == (3, 9)


def test_decoded_arrays_are_read_only():
    fb = egm.decode_robot(_robot_bytes())
    with pytest.raises(ValueError):
        fb.q_rad[0] = 1.0


def test_missing_speed_ref_reads_as_zero_velocity():
    msg = egm.EgmSensor()
    msg.header.seqno = 1
    msg.planned.joints.joints.extend([1.0] * 6)
    s = egm.decode_sensor(msg.SerializeToString())
    assert not s.qd_rad_s.any()


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\xff\xff\xff",
        b"\x0a\x05\x08",  # truncated header
        _robot_bytes()[:-3],
        _robot_bytes(deg=(1, 2, 3, 4, 5)),
        _robot_bytes(deg=(1, 2, 3, 4, 5, 6, 7)),
        _robot_bytes(deg=(1, 2, math.nan, 4, 5, 6)),
        _robot_bytes(deg=(1, 2, 3, math.inf, 5, 6)),
        _robot_bytes(deg=(1e308, 2, 3, 4, 5, 6)),  # finite but absurd
        _len_field(2, _len_field(1, _joints([0] * 6))),  # no header
        _len_field(1, _int_field(1, 3)),  # header only
    ],
)
def test_malformed_robot_bytes_raise_a_project_error(data):
    with pytest.raises(egm.EgmDecodeError) as info:
        egm.decode_robot(data)
    assert isinstance(info.value, ThinkfastError) and str(info.value)


@pytest.mark.parametrize(
    "q, qd",
    [
        ([0.0] * 5, [0.0] * 6),
        ([0.0] * 6, [0.0] * 7),
        ([0.0] * 5 + [math.nan], [0.0] * 6),
        ([0.0] * 6, [math.inf] + [0.0] * 5),
        ([0.0] * 6, None),
        (["a"] * 6, [0.0] * 6),
    ],
)
def test_encoders_refuse_bad_setpoints(q, qd):
    with pytest.raises(egm.EgmEncodeError):
        egm.encode_sensor(1, 1, q, qd)


def test_random_mutations_only_ever_raise_egm_decode_error():
    rng = np.random.default_rng(1)
    good = egm.encode_robot(1, 2, np.zeros(6))
    for _ in range(3000):
        b = bytearray(good)
        for _ in range(int(rng.integers(1, 4))):
            b[int(rng.integers(len(b)))] = int(rng.integers(256))
        b = bytes(b[: int(rng.integers(0, len(b) + 1))])
        try:
            fb = egm.decode_robot(b)
        except egm.EgmDecodeError:
            continue
        assert fb.q_rad.shape == (6,) and np.isfinite(fb.q_rad).all()


def _runtime_sensor_bytes(seqno, tm, q, qd, mtype):
    """The same EgmSensor serialized by the protobuf runtime."""
    msg = egm.EgmSensor()
    msg.header.seqno, msg.header.tm, msg.header.mtype = seqno & egm.UINT32, tm & egm.UINT32, mtype
    msg.planned.joints.joints.extend(np.degrees(q).tolist())
    msg.speedRef.joints.joints.extend(np.degrees(qd).tolist())
    return msg.SerializeToString()


def test_sensor_bytes_are_the_protobuf_runtimes_own():
    rng = np.random.default_rng(3)
    edges = [0, 1, 127, 128, 16383, 16384, 2**31, 2**32 - 1, 2**32, 2**40 + 5]
    for k in range(3000):
        q = rng.uniform(-7, 7, 6) * 10.0 ** rng.integers(-300, 3, 6)
        q[rng.random(6) < 0.1] = -0.0
        qd = rng.uniform(-10, 10, 6)
        seq = edges[k % len(edges)] if k < 100 else int(rng.integers(0, 2**33))
        tm, mtype = int(rng.integers(0, 2**33)), int(rng.integers(0, 5))
        data = egm.encode_sensor(seq, tm, q, qd, mtype=mtype)
        assert data == _runtime_sensor_bytes(seq, tm, q, qd, mtype)
        body = egm.sensor_body(q, qd)  # encoded ahead of the header: the same bytes
        assert egm.encode_sensor(seq, tm, None, None, mtype=mtype, body=body) == data


def test_a_body_encoded_ahead_refuses_what_the_encoder_refuses():
    for q, qd in ((np.zeros(5), np.zeros(6)), (np.zeros(6), np.r_[np.zeros(5), np.nan])):
        with pytest.raises(egm.EgmEncodeError):
            egm.sensor_body(q, qd)


def test_unknown_message_type_is_refused():
    with pytest.raises(egm.EgmEncodeError):
        egm.encode_sensor(1, 1, np.zeros(6), np.zeros(6), mtype=9)
