"""Simulated ABB controller: an EGM client with a servo model, in lockstep or over real UDP.

:class:`SimController` is the deterministic core (no sockets, no clocks): it makes ``EgmRobot``
messages from its state, takes ``EgmSensor`` replies as commands, and integrates the servo model
with :meth:`SimController.step`. :class:`~thinkfast.sim.controller_runner.ControllerRunner`
puts it on a UDP socket and exchanges one message pair every 4 ms (or flat out), as a real
controller does. Simulated time advances by the nominal ``dt`` per exchange (s), whatever the
wall clock does.

The servo model (transport delay, reference low pass, position and velocity loops; every number
an assumption in :class:`ServoConfig`) and the header stamps (``seqno``, ``tm``,
:class:`ClockJitter`): docs/EGM_CONTROLLER.md, "The simulated controller".
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import threading
from typing import NamedTuple

import numpy as np

from thinkfast.config import spec
from thinkfast.contract.egm import EgmDecodeError, decode_sensor, encode_robot

LIMITS = ("q_min", "q_max", "v_max", "a_max")  # the arm's limits: the robot's unless given


@dataclasses.dataclass(frozen=True)
class ServoConfig:
    """Simulated controller: cycle, lag model and the arm's limits.

    The limits (:data:`LIMITS`) left empty are the robot's (:func:`servo_for`: URDF position
    limits, robot.toml's velocity and acceleration limits); one given holds a value per joint.
    """

    dt: float = spec(0.004, doc="EGM cycle", unit="s", lo=0.0, lo_open=True)
    delay: float = spec(0.008, doc="transport + input processing delay", unit="s", lo=0.0)
    lowpass_hz: float = spec(
        20.0, doc="reference low-pass bandwidth", unit="Hz", lo=0.0, lo_open=True
    )
    kp: float = spec(20.0, doc="position gain", unit="1/s", lo=0.0)
    kff: float = spec(1.0, doc="speed feed-forward gain", lo=0.0)
    tau_v: float = spec(0.01, doc="velocity loop time constant", unit="s", lo=0.0, lo_open=True)
    substep: float = spec(0.001, doc="integration step", unit="s", lo=0.0, lo_open=True)
    q_min: tuple[float, ...] = spec(
        (), unit="rad", doc="lower position limits (empty: the robot's)"
    )
    q_max: tuple[float, ...] = spec(
        (), unit="rad", doc="upper position limits (empty: the robot's)"
    )
    v_max: tuple[float, ...] = spec(
        (), unit="rad/s", lo=0.0, doc="velocity limits (empty: the robot's)"
    )
    a_max: tuple[float, ...] = spec(
        (), unit="rad/s^2", doc="acceleration limits (empty: the robot's)"
    )


def servo_for(robot, servo: ServoConfig | None = None, source: str = "servo") -> ServoConfig:
    """``servo`` (default :class:`ServoConfig`) with the limits it leaves empty taken from
    ``robot`` (:class:`~thinkfast.robot.model.Robot`: URDF position limits, robot.toml's
    ``max_velocity`` and ``max_acceleration``): the simulated arm is the robot's.

    Raises:
        ConfigError: a limit given with another length than the robot's joints (names
            ``source`` and the key).
    """
    from thinkfast.errors import ConfigError

    servo = ServoConfig() if servo is None else servo
    own = dict(zip(LIMITS, (robot.q_lower, robot.q_upper, robot.v_max, robot.a_max), strict=True))
    out = {}
    for key in LIMITS:
        given = getattr(servo, key)
        if given and len(given) != robot.n_joints:
            raise ConfigError(source, key, f"expected {robot.n_joints} values, one per joint of "
                              f"{robot.name}, got {len(given)}")  # fmt: skip
        out[key] = tuple(given) if given else tuple(float(x) for x in own[key])
    return dataclasses.replace(servo, **out)


@functools.cache
def _default_robot_servo() -> dict:
    """The default robot's limits, for a :class:`SimController` built without a robot (a bare
    servo model in tests and benchmarks; every simulator of the package passes
    :func:`servo_for` of its robot)."""
    from thinkfast.robot.model import load_robot

    servo = servo_for(load_robot())
    return {k: getattr(servo, k) for k in LIMITS}


def _resolved(config: ServoConfig) -> ServoConfig:
    if all(getattr(config, k) for k in LIMITS):
        return config
    fill = _default_robot_servo()
    return dataclasses.replace(config, **{k: getattr(config, k) or fill[k] for k in LIMITS})


@dataclasses.dataclass(frozen=True)
class ClockJitter:
    """A controller clock that is not hard real-time: how ``tm`` departs from the servo's time.

    ``tm`` = round(1000 (t + jumps) + U(-jitter_ms, jitter_ms)), where ``t`` is the servo's time
    (one cycle per packet) and ``jumps`` the sum of the stalls so far; with probability
    ``repeat`` a stamp repeats the previous one. Never decreasing.
    """

    jitter_ms: float = spec(
        1.0, doc="stamp jitter around the cycle (uniform +-)", unit="ms", lo=0.0
    )
    repeat: float = spec(0.01, doc="probability that a stamp repeats the last one", lo=0.0, hi=1.0)
    stall_rate: float = spec(0.5, doc="clock jumps per second of servo time", unit="1/s", lo=0.0)
    stall_ms: tuple[float, float] = spec((10.0, 50.0), doc="range of a jump", unit="ms", length=2)
    seed: int = spec(0, doc="seed of the stamps' randomness")


class Stamps:
    """``tm`` stamps of a :class:`ClockJitter` clock (deterministic per seed)."""

    def __init__(self, clock: ClockJitter):
        self.clock, self.rng = clock, np.random.default_rng(clock.seed)
        self.jumps_ms, self.last = 0.0, None

    def tm(self, t: float, dt: float) -> int:
        c, rng = self.clock, self.rng
        if c.stall_rate > 0 and rng.random() < c.stall_rate * dt:
            self.jumps_ms += float(rng.uniform(*c.stall_ms))
        if self.last is not None and rng.random() < c.repeat:
            return self.last
        tm = round(1000.0 * t + self.jumps_ms + rng.uniform(-c.jitter_ms, c.jitter_ms))
        self.last = tm if self.last is None else max(tm, self.last)
        return self.last


class JointHistory(NamedTuple):
    """Recorded motion: ``t`` [s] (T,), ``q`` [rad] (T, n), ``qd`` [rad/s] (T, n) (n joints)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray


class SimController:
    """Deterministic simulated controller (servo model + EGM message handling).

    Args:
        config: servo model and limits (limits left empty: the default robot's; a simulator
            of a robot passes :func:`servo_for` of it).
        q0: initial joint angles [rad], shape (n,); zeros by default.
        max_history: keep only this many recent history samples and commands (None: all; a
            long run at 250 Hz would otherwise grow without bound).
        clock: ``tm`` stamps of a clock that is not hard real-time (None: exact, whole ms of
            the servo's time).

    Attributes:
        n: the arm's joints (one per value of each limit of ``config``).
    """

    def __init__(
        self,
        config: ServoConfig = ServoConfig(),
        q0=None,
        max_history: int | None = None,
        clock: ClockJitter | None = None,
    ):
        self.config = config = _resolved(config)
        self._stamps = None if clock is None else Stamps(clock)
        self.n = n = len(config.q_min)  # the arm's joints (the robot's: servo_for)
        self.q = np.zeros(n) if q0 is None else np.array(q0, dtype=float).reshape(n)
        self.qd = np.zeros(n)
        self.t = 0.0
        self.seqno = 0
        self.malformed = 0
        self._ref = (self.q.copy(), np.zeros(n))  # active (q_ref, qd_ref) after the delay
        self._filt = (self.q.copy(), np.zeros(n))  # low-passed reference
        self._queue: collections.deque = collections.deque()
        self._lock = threading.Lock()
        self._hist: collections.deque[tuple[float, np.ndarray, np.ndarray]] = collections.deque(
            [(0.0, self.q.copy(), self.qd)], maxlen=max_history
        )
        self._cmds: collections.deque[tuple[float, np.ndarray, np.ndarray]] = collections.deque(
            maxlen=max_history
        )
        q_min, q_max, v_max = (np.array(x) for x in (config.q_min, config.q_max, config.v_max))
        self._a_max = np.array(config.a_max)
        # Per joint (q_min, q_max, v_max, -v_max, a_max, -a_max), negated as arrays are.
        lim = (q_min, q_max, v_max, -v_max, self._a_max, -self._a_max)
        self._joint_limits = np.array(lim, dtype=float).T.tolist()
        # What the controller reports in every EgmRobot. Motors off, or EGM motion not running
        # (MCI stopped), the arm stops and references are ignored; RAPID stopped ends EGM too.
        self.motors_on = True
        self.mci_running = True
        self.rapid_running: bool | None = True

    @property
    def following(self) -> bool:
        """The servo follows the sensor's references (motors on, MCI and RAPID running)."""
        return self.motors_on and self.mci_running and self.rapid_running is not False

    def header(self) -> tuple[int, int]:
        """``(seqno, tm)`` of the next ``EgmRobot``: sequence number +1, time stamp [ms]."""
        self.seqno += 1
        if self._stamps is None:
            return self.seqno, int(round(self.t * 1000.0))
        return self.seqno, self._stamps.tm(self.t, self.config.dt)

    def robot_message(self) -> bytes:
        """The next ``EgmRobot`` datagram: current joint angles, :meth:`header`."""
        seqno, tm = self.header()
        return encode_robot(
            seqno,
            tm,
            self.q,
            motors_on=self.motors_on,
            mci_running=self.mci_running,
            rapid_running=self.rapid_running,
        )

    def handle_sensor(self, data: bytes, t: float | None = None) -> bool:
        """Take one ``EgmSensor`` datagram as a command received at ``t`` [s] (default: now).

        Returns:
            False (and counts ``malformed``) if the datagram is not a usable ``EgmSensor``.
        """
        try:
            cmd = decode_sensor(data)
        except EgmDecodeError:
            self.malformed += 1
            return False
        self.command(cmd.q_rad, cmd.qd_rad_s, t)
        return True

    def command(self, q_ref, qd_ref, t: float | None = None) -> None:
        """Queue a position [rad] and speed [rad/s] reference, shape (n,), received at ``t``."""
        t = self.t if t is None else t
        q_ref, qd_ref = np.array(q_ref, dtype=float), np.array(qd_ref, dtype=float)
        with self._lock:
            self._queue.append((t + self.config.delay, q_ref, qd_ref))
            self._cmds.append((t, q_ref, qd_ref))

    def step(self, dt: float) -> None:
        """Integrate the servo model over ``dt`` [s] and record one history sample."""
        cfg, nj = self.config, self.n  # nj: joints
        n = max(1, math.ceil(dt / cfg.substep - 1e-9))
        h = dt / n
        alpha = 1.0 - math.exp(-2.0 * math.pi * cfg.lowpass_hz * h)
        with self._lock:
            fq, fqd = self._filt
            if not self.following:  # references ignored: the servo stops the arm where it is
                self._queue.clear()
                qd = self.qd
                self._ref = (self.q + qd * np.abs(qd) / (2.0 * self._a_max), np.zeros(nj))
                fq, fqd = self._ref
            refs, ref, active = [], None, None
            for i in range(n):  # each substep's reference, as joint lists
                t = self.t + i * h
                while self._queue and self._queue[0][0] <= t + 1e-12:
                    self._ref = self._queue.popleft()[1:]
                if self._ref is not active:
                    active = self._ref
                    ref = tuple(_joint_list(r, nj) for r in active)
                refs.append(ref)
            gain = (cfg.kff, cfg.kp, h / cfg.tau_v)
            # A zero substep divides by zero: numpy scalars give inf/nan as the arrays did.
            h_j = h if h else np.float64(h)
            q, qd, fq, fqd = (_joint_list(x, nj) for x in (self.q, self.qd, fq, fqd))
            joints = [
                _servo_joint(
                    (q[j], qd[j], fq[j], fqd[j]), refs, j, self._joint_limits[j], gain, alpha, h_j
                )
                for j in range(nj)
            ]
            q, qd, fq, fqd = np.array(joints, dtype=float).T.copy()  # rows: C-contiguous (nj,)
            self._filt = (fq, fqd)
            self.q, self.qd, self.t = q, qd, self.t + dt
            self._hist.append((self.t, q.copy(), qd.copy()))

    def history(self) -> JointHistory:
        """Joint motion recorded so far (one sample per :meth:`step`, plus the start)."""
        with self._lock:
            rows = list(self._hist)
        return JointHistory(
            np.array([r[0] for r in rows]),
            np.array([r[1] for r in rows]),
            np.array([r[2] for r in rows]),
        )

    def commands(self) -> JointHistory:
        """Commands received so far: reception time [s], ``q_ref`` [rad], ``qd_ref`` [rad/s]."""
        with self._lock:
            rows = list(self._cmds)
        if not rows:
            return JointHistory(np.zeros(0), np.zeros((0, self.n)), np.zeros((0, self.n)))
        return JointHistory(
            np.array([r[0] for r in rows]),
            np.array([r[1] for r in rows]),
            np.array([r[2] for r in rows]),
        )


def _joint_list(x, n: int) -> list:
    """``n`` joint values as floats, broadcast as the array form would (an (n,) array is
    quick)."""
    if getattr(x, "shape", None) == (n,):
        return x.tolist()
    return np.broadcast_to(x, (n,)).tolist()


def _servo_joint(state, refs, j, limits, gain, alpha, h):
    """One joint through the substeps of :meth:`SimController.step`, on plain floats.

    Every expression keeps the order of operations of the array form; the min, max and clip
    are numpy's (``np.maximum``, ``np.minimum``, ``np.clip``): NaN propagates and a tie gives
    the second operand, so the result is the same to the bit.

    Args:
        state: ``(q, qd, fq, fqd)``: position [rad], speed [rad/s] and the low-passed
            reference position [rad] and speed [rad/s].
        refs: per substep, the active ``(q_ref, qd_ref)`` as lists of every joint [rad], [rad/s].
        j: joint index.
        limits: ``(q_min, q_max, v_max, -v_max, a_max, -a_max)`` of the joint [rad, rad/s,
            rad/s^2].
        gain: ``(kff, kp, h / tau_v)``.
        alpha: reference low-pass factor of one substep.
        h: substep [s].

    Returns:
        ``(q, qd, fq, fqd)`` after the substeps.
    """
    q, qd, f, fd = state
    lo, hi, vm, nvm, a, na = limits
    kff, kp, g = gain
    ah, nah = a * h, na * h
    sqrt = math.sqrt if a >= 0.0 else np.sqrt  # np.sqrt: nan (not an error) below zero
    for rq, rqd in refs:
        f, fd = f + alpha * (rq[j] - f), fd + alpha * (rqd[j] - fd)
        v = kff * fd + kp * (f - q)
        v = v if v > nvm or v != v else nvm
        v = v if v < vm or v != v else vm
        dv = (v - qd) * g
        dv = dv if dv > nah or dv != dv else nah
        dv = dv if dv < ah or dv != dv else ah
        # Soft limits: never faster than a stop at a_max / 2 (or one step) allows.
        up, dn = hi - q, q - lo
        up = up if up > 0.0 or up != up else 0.0
        dn = dn if dn > 0.0 or dn != dn else 0.0
        v_up, step_up = sqrt(a * up), up / h
        v_up = v_up if v_up < step_up or v_up != v_up else step_up
        v_dn, step_dn = sqrt(a * dn), dn / h
        v_dn = -(v_dn if v_dn < step_dn or v_dn != v_dn else step_dn)
        v_lo = nvm if nvm > v_dn or nvm != nvm else v_dn
        v_hi = vm if vm < v_up or vm != vm else v_up
        qd = qd + dv
        qd = qd if qd > v_lo or qd != qd else v_lo
        qd = qd if qd < v_hi or qd != qd else v_hi
        q = q + qd * h
        if q < lo or q > hi:  # a hard stop
            qd = 0.0
        q = q if q > lo or q != q else lo
        q = q if q < hi or q != q else hi
    return q, qd, f, fd
