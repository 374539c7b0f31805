"""ABB EGM wire format (protobuf proto2, package ``abb.egm``) and pure encode/decode helpers.

The schema is built at import time from a ``FileDescriptorProto`` (no ``protoc``), with the field
numbers of ABB's published ``egm.proto`` (docs/EGM_CONTROLLER.md). Only the fields thinkfast
uses are declared; everything else a controller sends (RobotWare 7 additions, Cartesian poses,
RAPID data, ...) arrives as unknown fields and is ignored by the parser.

Degrees live only here: the helpers take and return radians and rad/s; the wire carries degrees
and deg/s. Header fields that ABB declares ``required`` are declared ``optional`` here, which is
wire-identical and lets the decoders report a missing field as a clear :class:`EgmDecodeError`.

:func:`encode_sensor`, on the reply path of every EGM exchange, writes its bytes with ``struct``
(cheaper than the protobuf runtime: docs/BENCHMARKS.md, "EGM latency"): the same bytes as the
protobuf runtime writes for the same message (the tests compare them).
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from thinkfast.errors import ThinkfastError

N_JOINTS = 6
RAD_TO_DEG = 180.0 / math.pi
DEG_TO_RAD = math.pi / 180.0
UINT32 = 0xFFFFFFFF
MAX_ABS_DEG = 1e5  # decoders refuse joint values beyond this [deg, deg/s]: no axis turns 277 times

MSGTYPE_UNDEFINED, MSGTYPE_COMMAND, MSGTYPE_DATA, MSGTYPE_CORRECTION, MSGTYPE_PATH_CORRECTION = (
    range(5)
)
MOTORS_UNDEFINED, MOTORS_ON, MOTORS_OFF = range(3)
MCI_UNDEFINED, MCI_ERROR, MCI_STOPPED, MCI_RUNNING = range(4)
RAPID_UNDEFINED, RAPID_STOPPED, RAPID_RUNNING = range(3)


class EgmDecodeError(ThinkfastError):
    """An EGM datagram cannot be used: not protobuf, a required field missing, wrong joint count,
    or a non-finite value. The message says which."""


class EgmEncodeError(ThinkfastError):
    """Values handed to an encoder have the wrong shape or are not finite."""


def _schema() -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(name="thinkfast/abb_egm.proto", package="abb.egm")
    fdp.syntax = "proto2"
    F = descriptor_pb2.FieldDescriptorProto
    opt, rep = F.LABEL_OPTIONAL, F.LABEL_REPEATED

    def message(name, fields, enums=()):
        m = fdp.message_type.add(name=name)
        for ename, values in enums:
            e = m.enum_type.add(name=ename)
            for number, vname in enumerate(values):
                e.value.add(name=vname, number=number)
        for fname, number, label, ftype, type_name in fields:
            f = m.field.add(name=fname, number=number, label=label, type=ftype)
            if type_name:
                f.type_name = type_name

    msg, enum = F.TYPE_MESSAGE, F.TYPE_ENUM
    message(
        "EgmHeader",
        [
            ("seqno", 1, opt, F.TYPE_UINT32, ""),
            ("tm", 2, opt, F.TYPE_UINT32, ""),
            ("mtype", 3, opt, enum, ".abb.egm.EgmHeader.MessageType"),
        ],
        [("MessageType", ["MSGTYPE_UNDEFINED", "MSGTYPE_COMMAND", "MSGTYPE_DATA",
                          "MSGTYPE_CORRECTION", "MSGTYPE_PATH_CORRECTION"])],
    )  # fmt: skip
    message("EgmJoints", [("joints", 1, rep, F.TYPE_DOUBLE, "")])
    for name in ("EgmFeedBack", "EgmPlanned", "EgmSpeedRef"):
        message(name, [("joints", 1, opt, msg, ".abb.egm.EgmJoints")])
    message(
        "EgmMotorState",
        [("state", 1, opt, enum, ".abb.egm.EgmMotorState.MotorStateType")],
        [("MotorStateType", ["MOTORS_UNDEFINED", "MOTORS_ON", "MOTORS_OFF"])],
    )
    message(
        "EgmMCIState",
        [("state", 1, opt, enum, ".abb.egm.EgmMCIState.MCIStateType")],
        [("MCIStateType", ["MCI_UNDEFINED", "MCI_ERROR", "MCI_STOPPED", "MCI_RUNNING"])],
    )
    message(
        "EgmRapidCtrlExecState",
        [("state", 1, opt, enum, ".abb.egm.EgmRapidCtrlExecState.RapidCtrlExecStateType")],
        [("RapidCtrlExecStateType", ["RAPID_UNDEFINED", "RAPID_STOPPED", "RAPID_RUNNING"])],
    )
    message(
        "EgmRobot",
        [
            ("header", 1, opt, msg, ".abb.egm.EgmHeader"),
            ("feedBack", 2, opt, msg, ".abb.egm.EgmFeedBack"),
            ("planned", 3, opt, msg, ".abb.egm.EgmPlanned"),
            ("motorState", 4, opt, msg, ".abb.egm.EgmMotorState"),
            ("mciState", 5, opt, msg, ".abb.egm.EgmMCIState"),
            ("rapidExecState", 8, opt, msg, ".abb.egm.EgmRapidCtrlExecState"),
        ],
    )
    message(
        "EgmSensor",
        [
            ("header", 1, opt, msg, ".abb.egm.EgmHeader"),
            ("planned", 2, opt, msg, ".abb.egm.EgmPlanned"),
            ("speedRef", 3, opt, msg, ".abb.egm.EgmSpeedRef"),
        ],
    )
    return fdp


# A private pool: another module registering its own abb.egm schema cannot clash with this one.
_POOL = descriptor_pool.DescriptorPool()
_FILE = _POOL.Add(_schema())
EgmHeader = message_factory.GetMessageClass(_POOL.FindMessageTypeByName("abb.egm.EgmHeader"))
EgmJoints = message_factory.GetMessageClass(_POOL.FindMessageTypeByName("abb.egm.EgmJoints"))
EgmRobot = message_factory.GetMessageClass(_POOL.FindMessageTypeByName("abb.egm.EgmRobot"))
EgmSensor = message_factory.GetMessageClass(_POOL.FindMessageTypeByName("abb.egm.EgmSensor"))


class RobotFeedback(NamedTuple):
    """What the controller reports in one ``EgmRobot`` message.

    Attributes:
        seqno: controller sequence number (uint32).
        tm_ms: controller time stamp [ms] (uint32, wraps), None when the header has none.
        q_rad: measured joint angles [rad], shape (6,), read-only.
        motors_on: ``motorState`` is ``MOTORS_ON``.
        mci_running: ``mciState`` is ``MCI_RUNNING`` (the EGM motion is active).
        rapid_running: ``rapidExecState`` is ``RAPID_RUNNING``; None when the controller does
            not report it.

    A missing ``motorState`` or ``mciState`` reads as off / stopped: the daemon commands motion
    only when the controller says both are on (:attr:`ready`).
    """

    seqno: int
    tm_ms: int | None
    q_rad: np.ndarray
    motors_on: bool
    mci_running: bool
    rapid_running: bool | None = None

    @property
    def ready(self) -> bool:
        """The controller follows references: motors on, EGM motion running, RAPID not stopped."""
        return self.motors_on and self.mci_running and self.rapid_running is not False


class SensorCommand(NamedTuple):
    """What the sensor (thinkfast) sends in one ``EgmSensor`` message.

    Attributes:
        seqno: sensor sequence number (uint32).
        tm_ms: sensor time stamp [ms] (uint32, wraps).
        mtype: header message type (``MSGTYPE_CORRECTION`` from thinkfast).
        q_rad: planned joint angles [rad], shape (6,), read-only.
        qd_rad_s: speed reference [rad/s], shape (6,), read-only; zeros if ``speedRef`` is absent.
    """

    seqno: int
    tm_ms: int
    mtype: int
    q_rad: np.ndarray
    qd_rad_s: np.ndarray


def _wire_joints(values, what: str) -> list[float]:
    """Six finite radian values -> list of six degrees (raises :class:`EgmEncodeError`)."""
    try:
        out = [float(v) * RAD_TO_DEG for v in values]
    except (TypeError, ValueError) as exc:
        raise EgmEncodeError(f"{what}: expected {N_JOINTS} numbers ({exc})") from None
    if len(out) != N_JOINTS:
        raise EgmEncodeError(f"{what}: expected {N_JOINTS} values, got {len(out)}")
    if not all(map(math.isfinite, out)):
        raise EgmEncodeError(f"{what}: non-finite value in {out}")
    return out


def _joints_from_wire(joints, what: str) -> np.ndarray:
    deg = list(joints)  # plain floats: cheaper than numpy's calls for six (on every packet)
    if len(deg) != N_JOINTS:
        raise EgmDecodeError(f"{what}: expected {N_JOINTS} joints, got {len(deg)}")
    for x in deg:
        if not -MAX_ABS_DEG <= x <= MAX_ABS_DEG:  # NaN compares false
            raise EgmDecodeError(
                f"{what}: non-finite or absurd joint value (|deg| > {MAX_ABS_DEG:g})"
            )
    q = np.array(deg) * DEG_TO_RAD
    q.setflags(write=False)
    return q


def _parse(cls, data: bytes):
    msg = cls()
    try:
        msg.ParseFromString(bytes(data))
    except Exception as exc:  # untrusted bytes: any parser failure is a decode error
        raise EgmDecodeError(f"not a valid {cls.DESCRIPTOR.name} message ({exc})") from None
    if not msg.HasField("header"):
        raise EgmDecodeError(f"{cls.DESCRIPTOR.name}: no header")
    return msg


def encode_sensor(
    seqno: int,
    tm_ms: int,
    q_rad,
    qd_rad_s,
    mtype: int = MSGTYPE_CORRECTION,
    body: bytes | None = None,
) -> bytes:
    """Serialize one ``EgmSensor`` (planned joints + speed reference).

    Args:
        seqno: sequence number, taken modulo 2**32.
        tm_ms: time stamp [ms], taken modulo 2**32.
        q_rad: joint position setpoint [rad], 6 finite values.
        qd_rad_s: joint velocity setpoint [rad/s], 6 finite values.
        mtype: header message type.
        body: :func:`sensor_body` of ``q_rad, qd_rad_s``, encoded ahead (None: encoded here).

    Returns:
        The datagram payload (degrees and deg/s on the wire).

    Raises:
        EgmEncodeError: wrong count or a non-finite value (nothing unsafe is ever serialized).
    """
    if mtype not in _MTYPES:
        raise EgmEncodeError(f"mtype {mtype!r} is not one of {list(_MTYPES)}")
    if body is None:
        body = sensor_body(q_rad, qd_rad_s)
    header = b"".join(
        (
            b"\x08",
            _varint(int(seqno) & UINT32),
            b"\x10",
            _varint(int(tm_ms) & UINT32),
            _MTYPES[mtype],
        )
    )
    return b"".join((b"\x0a", bytes((len(header),)), header, body))


def sensor_body(q_rad, qd_rad_s) -> bytes:
    """The ``planned`` and ``speedRef`` fields of an ``EgmSensor`` (all of it but the header),
    to encode ahead of the header (:func:`encode_sensor`'s ``body``).

    Raises:
        EgmEncodeError: wrong count or a non-finite value.
    """
    q = _wire_joints(q_rad, "planned joints")
    qd = _wire_joints(qd_rad_s, "speedRef joints")
    return b"".join((_PLANNED, _joints(q), _SPEED_REF, _joints(qd)))


# EgmSensor on the wire, field by field (tag = number << 3 | wire type), as protobuf writes it:
# header (1, length-delimited): seqno (1, varint), tm (2, varint), mtype (3, varint); then
# planned (2) and speedRef (3), each holding EgmJoints (1) with 6 unpacked doubles (1, 64-bit).
_DOUBLE_TAG = 1 << 3 | 1
_JOINTS = struct.Struct("<" + "Bd" * N_JOINTS)  # each double after its tag byte
_JOINTS_LEN = _JOINTS.size  # 54
_PLANNED = bytes((2 << 3 | 2, _JOINTS_LEN + 2, 1 << 3 | 2, _JOINTS_LEN))
_SPEED_REF = bytes((3 << 3 | 2, _JOINTS_LEN + 2, 1 << 3 | 2, _JOINTS_LEN))
_MTYPES = {m: bytes((3 << 3, m)) for m in range(5)}  # MSGTYPE_UNDEFINED .. PATH_CORRECTION


def _joints(v: list[float]) -> bytes:
    """The repeated ``EgmJoints.joints`` field of 6 doubles, unpacked (as proto2 writes it)."""
    t = _DOUBLE_TAG
    return _JOINTS.pack(t, v[0], t, v[1], t, v[2], t, v[3], t, v[4], t, v[5])


def _varint(n: int) -> bytes:
    """Protobuf base-128 varint of ``n`` >= 0."""
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def decode_robot(data: bytes) -> RobotFeedback:
    """Parse one ``EgmRobot`` datagram.

    Args:
        data: the UDP payload.

    Returns:
        The feedback, joints in radians.

    Raises:
        EgmDecodeError: not protobuf, no header, no ``feedBack.joints``, not exactly 6 joints, or
            a joint value that is non-finite or beyond ``MAX_ABS_DEG``.
    """
    msg = _parse(EgmRobot, data)
    if not (msg.HasField("feedBack") and msg.feedBack.HasField("joints")):
        raise EgmDecodeError("EgmRobot: no feedBack.joints")
    q = _joints_from_wire(msg.feedBack.joints.joints, "EgmRobot feedBack")
    header = msg.header
    return RobotFeedback(
        header.seqno,
        header.tm if header.HasField("tm") else None,
        q,
        msg.motorState.state == MOTORS_ON,
        msg.mciState.state == MCI_RUNNING,
        msg.rapidExecState.state == RAPID_RUNNING if msg.HasField("rapidExecState") else None,
    )


def encode_robot(
    seqno: int,
    tm_ms: int,
    q_rad,
    motors_on: bool = True,
    mci_running: bool = True,
    planned_q_rad=None,
    rapid_running: bool | None = True,
) -> bytes:
    """Serialize one ``EgmRobot`` as a controller would (simulator and tests).

    Args:
        seqno: sequence number, modulo 2**32.
        tm_ms: controller time stamp [ms], modulo 2**32.
        q_rad: measured joint angles [rad], 6 finite values.
        motors_on: motor state ``MOTORS_ON`` (else ``MOTORS_OFF``).
        mci_running: MCI state ``MCI_RUNNING`` (else ``MCI_STOPPED``).
        planned_q_rad: optional planned joint angles [rad], 6 values.
        rapid_running: RAPID execution state ``RAPID_RUNNING`` (False: ``RAPID_STOPPED``; None:
            not sent, as by a controller that does not report it).

    Raises:
        EgmEncodeError: wrong count or a non-finite value.
    """
    msg = EgmRobot()
    msg.header.seqno = int(seqno) & UINT32
    msg.header.tm = int(tm_ms) & UINT32
    msg.header.mtype = MSGTYPE_DATA
    msg.feedBack.joints.joints.extend(_wire_joints(q_rad, "feedBack joints"))
    if planned_q_rad is not None:
        msg.planned.joints.joints.extend(_wire_joints(planned_q_rad, "planned joints"))
    msg.motorState.state = MOTORS_ON if motors_on else MOTORS_OFF
    msg.mciState.state = MCI_RUNNING if mci_running else MCI_STOPPED
    if rapid_running is not None:
        msg.rapidExecState.state = RAPID_RUNNING if rapid_running else RAPID_STOPPED
    return msg.SerializeToString()


def decode_sensor(data: bytes) -> SensorCommand:
    """Parse one ``EgmSensor`` datagram (simulated controller and tests).

    Raises:
        EgmDecodeError: not protobuf, no header, no ``planned.joints``, not exactly 6 values in
            ``planned`` or ``speedRef``, or a value non-finite or beyond ``MAX_ABS_DEG``.
    """
    msg = _parse(EgmSensor, data)
    if not (msg.HasField("planned") and msg.planned.HasField("joints")):
        raise EgmDecodeError("EgmSensor: no planned.joints")
    q = _joints_from_wire(msg.planned.joints.joints, "EgmSensor planned")
    if msg.HasField("speedRef") and msg.speedRef.HasField("joints"):
        qd = _joints_from_wire(msg.speedRef.joints.joints, "EgmSensor speedRef")
    else:
        qd = np.zeros(N_JOINTS)
        qd.setflags(write=False)
    return SensorCommand(msg.header.seqno, msg.header.tm, msg.header.mtype, q, qd)
