"""The fault campaign's own EGM message classes: ABB's published ``egm.proto`` (V1.1), built here.

Independent of the daemon's :mod:`thinkfast.contract.egm` on purpose: the checker decodes
every ``EgmSensor`` with a schema the daemon did not write, so a wrong field number or wire type
on the daemon's side cannot cancel out. The schema declares every message of ABB's file (field
numbers, types and labels as published, ``required`` included) in a private descriptor pool; the
controller fills in the fields a real controller sends (Cartesian poses, clocks, MCI state,
convergence flag, utilisation), which the daemon must tolerate.

Degrees and millimetres are what the wire carries; the helpers here convert joints to radians.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

_F = descriptor_pb2.FieldDescriptorProto
_OPT, _REQ, _REP = _F.LABEL_OPTIONAL, _F.LABEL_REQUIRED, _F.LABEL_REPEATED
_D, _U32, _U64, _B = _F.TYPE_DOUBLE, _F.TYPE_UINT32, _F.TYPE_UINT64, _F.TYPE_BOOL
_M, _E = _F.TYPE_MESSAGE, _F.TYPE_ENUM

# message -> [(field, number, label, type, type name)], enums nested as (name, values)
_MESSAGES = {
    "EgmHeader": (
        [("seqno", 1, _OPT, _U32, ""), ("tm", 2, _OPT, _U32, ""),
         ("mtype", 3, _OPT, _E, "EgmHeader.MessageType")],
        [("MessageType", ("MSGTYPE_UNDEFINED", "MSGTYPE_COMMAND", "MSGTYPE_DATA",
                          "MSGTYPE_CORRECTION", "MSGTYPE_PATH_CORRECTION"))],
    ),
    "EgmCartesian": ([("x", 1, _REQ, _D, ""), ("y", 2, _REQ, _D, ""), ("z", 3, _REQ, _D, "")], []),
    "EgmQuaternion": (
        [("u0", 1, _REQ, _D, ""), ("u1", 2, _REQ, _D, ""), ("u2", 3, _REQ, _D, ""),
         ("u3", 4, _REQ, _D, "")], [],
    ),
    "EgmEuler": ([("x", 1, _REQ, _D, ""), ("y", 2, _REQ, _D, ""), ("z", 3, _REQ, _D, "")], []),
    "EgmClock": ([("sec", 1, _REQ, _U64, ""), ("usec", 2, _REQ, _U64, "")], []),
    "EgmPose": (
        [("pos", 1, _OPT, _M, "EgmCartesian"), ("orient", 2, _OPT, _M, "EgmQuaternion"),
         ("euler", 3, _OPT, _M, "EgmEuler")], [],
    ),
    "EgmCartesianSpeed": ([("value", 1, _REP, _D, "")], []),
    "EgmJoints": ([("joints", 1, _REP, _D, "")], []),
    "EgmExternalJoints": ([("joints", 1, _REP, _D, "")], []),
    "EgmPlanned": (
        [("joints", 1, _OPT, _M, "EgmJoints"), ("cartesian", 2, _OPT, _M, "EgmPose"),
         ("externalJoints", 3, _OPT, _M, "EgmJoints"), ("time", 4, _OPT, _M, "EgmClock")], [],
    ),
    "EgmSpeedRef": (
        [("joints", 1, _OPT, _M, "EgmJoints"), ("cartesians", 2, _OPT, _M, "EgmCartesianSpeed"),
         ("externalJoints", 3, _OPT, _M, "EgmJoints")], [],
    ),
    "EgmPathCorr": ([("pos", 1, _REQ, _M, "EgmCartesian"), ("age", 2, _REQ, _U32, "")], []),
    "EgmFeedBack": (
        [("joints", 1, _OPT, _M, "EgmJoints"), ("cartesian", 2, _OPT, _M, "EgmPose"),
         ("externalJoints", 3, _OPT, _M, "EgmJoints"), ("time", 4, _OPT, _M, "EgmClock")], [],
    ),
    "EgmMotorState": (
        [("state", 1, _REQ, _E, "EgmMotorState.MotorStateType")],
        [("MotorStateType", ("MOTORS_UNDEFINED", "MOTORS_ON", "MOTORS_OFF"))],
    ),
    "EgmMCIState": (
        [("state", 1, _REQ, _E, "EgmMCIState.MCIStateType")],
        [("MCIStateType", ("MCI_UNDEFINED", "MCI_ERROR", "MCI_STOPPED", "MCI_RUNNING"))],
    ),
    "EgmRapidCtrlExecState": (
        [("state", 1, _REQ, _E, "EgmRapidCtrlExecState.RapidCtrlExecStateType")],
        [("RapidCtrlExecStateType", ("RAPID_UNDEFINED", "RAPID_STOPPED", "RAPID_RUNNING"))],
    ),
    "EgmTestSignals": ([("signals", 1, _REP, _D, "")], []),
    "EgmMeasuredForce": ([("force", 1, _REP, _D, "")], []),
    "EgmRobot": (
        [("header", 1, _OPT, _M, "EgmHeader"), ("feedBack", 2, _OPT, _M, "EgmFeedBack"),
         ("planned", 3, _OPT, _M, "EgmPlanned"), ("motorState", 4, _OPT, _M, "EgmMotorState"),
         ("mciState", 5, _OPT, _M, "EgmMCIState"), ("mciConvergenceMet", 6, _OPT, _B, ""),
         ("testSignals", 7, _OPT, _M, "EgmTestSignals"),
         ("rapidExecState", 8, _OPT, _M, "EgmRapidCtrlExecState"),
         ("measuredForce", 9, _OPT, _M, "EgmMeasuredForce"), ("utilizationRate", 10, _OPT, _D, "")],
        [],
    ),
    "EgmSensor": (
        [("header", 1, _OPT, _M, "EgmHeader"), ("planned", 2, _OPT, _M, "EgmPlanned"),
         ("speedRef", 3, _OPT, _M, "EgmSpeedRef")], [],
    ),
    "EgmSensorPathCorr": (
        [("header", 1, _OPT, _M, "EgmHeader"), ("pathCorr", 2, _OPT, _M, "EgmPathCorr")], [],
    ),
}  # fmt: skip


def _file() -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(name="faults/abb_egm_v1_1.proto", package="abb.egm")
    fdp.syntax = "proto2"
    for name, (fields, enums) in _MESSAGES.items():
        m = fdp.message_type.add(name=name)
        for ename, values in enums:
            e = m.enum_type.add(name=ename)
            for number, vname in enumerate(values):
                e.value.add(name=vname, number=number)
        for fname, number, label, ftype, tname in fields:
            f = m.field.add(name=fname, number=number, label=label, type=ftype)
            if tname:
                f.type_name = f".abb.egm.{tname}"
    return fdp


_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(_file())


def _cls(name: str):
    return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(f"abb.egm.{name}"))


EgmRobot, EgmSensor, EgmHeader = _cls("EgmRobot"), _cls("EgmSensor"), _cls("EgmHeader")
MSGTYPE_DATA, MSGTYPE_CORRECTION = 2, 3
MOTORS_ON, MCI_RUNNING, RAPID_RUNNING = 1, 3, 2
DEG = 180.0 / math.pi


class Reply(NamedTuple):
    """One decoded ``EgmSensor``: header fields, ``q`` [rad] and ``qd`` [rad/s] (6,) or None."""

    seqno: int
    tm: int
    mtype: int
    q: np.ndarray | None
    qd: np.ndarray | None


def robot_message(seqno: int, tm_ms: int, q, q_planned=None, unix_time: float = 0.0) -> bytes:
    """An ``EgmRobot`` as a RobotWare 6 controller fills it in (joint mode, MCI running).

    Args:
        seqno, tm_ms: header sequence number and controller time [ms] (taken modulo 2**32).
        q: measured joints [rad] (6,); any finite values (absurd ones included).
        q_planned: the controller's planned joints [rad] (6,), default ``q``.
        unix_time: feedback time stamp [s since 1970].
    """
    m = EgmRobot()
    m.header.seqno, m.header.tm, m.header.mtype = seqno & 0xFFFFFFFF, tm_ms & 0xFFFFFFFF, 2
    m.feedBack.joints.joints.extend(float(x) * DEG for x in q)
    m.feedBack.cartesian.pos.x, m.feedBack.cartesian.pos.y, m.feedBack.cartesian.pos.z = 800, 0, 1e3
    o = m.feedBack.cartesian.orient
    o.u0, o.u1, o.u2, o.u3 = 0.7071, 0.0, 0.7071, 0.0
    sec = int(unix_time)
    m.feedBack.time.sec, m.feedBack.time.usec = sec, int((unix_time - sec) * 1e6)
    m.planned.joints.joints.extend(float(x) * DEG for x in (q if q_planned is None else q_planned))
    m.motorState.state, m.mciState.state = MOTORS_ON, MCI_RUNNING
    m.mciConvergenceMet = True
    m.rapidExecState.state = RAPID_RUNNING
    m.utilizationRate = 12.5
    return m.SerializeToString()


def decode_reply(data: bytes) -> Reply | None:
    """Parse an ``EgmSensor`` datagram; None when protobuf refuses it or the header is missing.

    Joint lists of any length are returned as given (the checker judges them); absent joints give
    None. Values are converted from degrees to radians, non-finite ones kept.
    """
    m = EgmSensor()
    try:
        m.ParseFromString(bytes(data))
    except Exception:  # untrusted bytes: any parser failure means "not an EgmSensor"
        return None
    if not m.HasField("header"):
        return None
    q = qd = None
    if m.HasField("planned") and m.planned.HasField("joints"):
        q = np.array(m.planned.joints.joints, dtype=float) / DEG
    if m.HasField("speedRef") and m.speedRef.HasField("joints"):
        qd = np.array(m.speedRef.joints.joints, dtype=float) / DEG
    return Reply(m.header.seqno, m.header.tm, m.header.mtype, q, qd)
