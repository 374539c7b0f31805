"""The EGM codec against ABB's own compiled protobuf (``egm.proto`` as shipped, compiled, by
abb-robot-client 0.4.0), both directions: what the controller writes we read, what we write the
controller reads, field for field (angles in degrees on the wire)."""

from __future__ import annotations

import numpy as np
import pytest

from thinkfast.contract.egm import decode_robot, decode_sensor, encode_robot, encode_sensor

egm_pb2 = pytest.importorskip("abb_robot_client._egm_protobuf.egm_pb2")
RNG = np.random.default_rng(27)


def _abb_robot(seqno, tm, q_deg, motors, mci, rapid) -> bytes:
    """An EgmRobot as the controller's protobuf writes it (with fields we ignore too)."""
    m = egm_pb2.EgmRobot()
    m.header.seqno, m.header.tm = seqno, tm
    m.header.mtype = egm_pb2.EgmHeader.MSGTYPE_DATA
    m.feedBack.joints.joints.extend(q_deg)
    pose = m.feedBack.cartesian  # the TCP pose [mm], as the controller adds it
    pose.pos.x, pose.pos.y, pose.pos.z = 812.5, 0.0, 1210.0
    pose.orient.u0, pose.orient.u1, pose.orient.u2, pose.orient.u3 = 0.0, 0.0, 1.0, 0.0
    m.planned.joints.joints.extend(q_deg)
    m.motorState.state = (
        egm_pb2.EgmMotorState.MOTORS_ON if motors else egm_pb2.EgmMotorState.MOTORS_OFF
    )
    m.mciState.state = egm_pb2.EgmMCIState.MCI_RUNNING if mci else egm_pb2.EgmMCIState.MCI_STOPPED
    m.mciConvergenceMet = True
    m.rapidExecState.state = (egm_pb2.EgmRapidCtrlExecState.RAPID_RUNNING if rapid
                              else egm_pb2.EgmRapidCtrlExecState.RAPID_STOPPED)  # fmt: skip
    m.utilizationRate = 37.5  # % (a field thinkfast ignores)
    return m.SerializeToString()


@pytest.mark.parametrize("seed", range(5))
def test_what_abbs_protobuf_writes_we_read(seed):
    rng = np.random.default_rng(seed)
    q_deg = rng.uniform(-170, 170, 6)
    seqno, tm = int(rng.integers(0, 2**32)), int(rng.integers(0, 2**32))
    motors, mci, rapid = (bool(x) for x in rng.integers(0, 2, 3))
    fb = decode_robot(_abb_robot(seqno, tm, q_deg, motors, mci, rapid))
    assert (fb.seqno, fb.tm_ms) == (seqno, tm)
    np.testing.assert_allclose(np.degrees(fb.q_rad), q_deg, rtol=0, atol=1e-9)
    assert (fb.motors_on, fb.mci_running, fb.rapid_running) == (motors, mci, rapid)


@pytest.mark.parametrize("seed", range(5))
def test_what_we_write_abbs_protobuf_reads(seed):
    rng = np.random.default_rng(seed)
    q, qd = rng.uniform(-2.5, 2.5, 6), rng.uniform(-3.0, 3.0, 6)
    seqno, tm = int(rng.integers(0, 2**32)), int(rng.integers(0, 2**32))
    m = egm_pb2.EgmSensor()
    m.ParseFromString(encode_sensor(seqno, tm, q, qd))
    assert (m.header.seqno, m.header.tm) == (seqno, tm)
    assert m.header.mtype == egm_pb2.EgmHeader.MSGTYPE_CORRECTION
    np.testing.assert_allclose(list(m.planned.joints.joints), np.degrees(q), rtol=1e-12)
    np.testing.assert_allclose(list(m.speedRef.joints.joints), np.degrees(qd), rtol=1e-12)
    r = egm_pb2.EgmRobot()  # and the simulator's EgmRobot reads as the controller's
    r.ParseFromString(encode_robot(seqno, tm, q, motors_on=True, mci_running=False))
    assert (r.header.seqno, r.header.tm) == (seqno, tm)
    np.testing.assert_allclose(list(r.feedBack.joints.joints), np.degrees(q), rtol=1e-12)
    assert r.motorState.state == egm_pb2.EgmMotorState.MOTORS_ON
    assert r.mciState.state == egm_pb2.EgmMCIState.MCI_STOPPED


def test_abbs_sensor_message_reads_back_through_our_decoder():
    q_deg, qd_deg = RNG.uniform(-90, 90, 6), RNG.uniform(-50, 50, 6)
    m = egm_pb2.EgmSensor()
    m.header.seqno, m.header.tm = 7, 1234
    m.header.mtype = egm_pb2.EgmHeader.MSGTYPE_CORRECTION
    m.planned.joints.joints.extend(q_deg)
    m.speedRef.joints.joints.extend(qd_deg)
    cmd = decode_sensor(m.SerializeToString())
    np.testing.assert_allclose(np.degrees(cmd.q_rad), q_deg, atol=1e-9)
    np.testing.assert_allclose(np.degrees(cmd.qd_rad_s), qd_deg, atol=1e-9)
    assert (cmd.seqno, cmd.tm_ms) == (7, 1234)
