"""Simulated dynamics records: an excitation played through the simulated controller, recorded.

The excitation moves every joint at once, back and forth about home (jerk-limited Ruckig moves
from rest to rest, each joint at its own limits, then a short rest): gentle moves (half the
robot's velocity, acceleration and jerk limits: the arm follows, so they measure the lag) and
hard ones (``hard`` times the robot's
acceleration and jerk: beyond what the arm achieves, so they measure its limits). Each 4 ms cycle
the simulated controller (:class:`~thinkfast.sim.controller.SimController`, servo model of
``ServoConfig``) reports its joints (plus ``feedback_noise``), takes the setpoint and steps, and
the exchange is written by the daemon's own flight recorder (``egm`` rows of a
``thinkfast-record`` v2 file), so ``thinkfast-calib dynamics`` reads it like a real run's.

Known answers: the servo model tracks a ramp with a lag of about ``delay + 1 / (2 pi
lowpass_hz)`` (:func:`servo_lag`) and accelerates at most at ``a_max``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
from ruckig import InputParameter, OutputParameter, Result, Ruckig, Synchronization

from thinkfast.errors import RecorderError
from thinkfast.record.recorder import Recorder
from thinkfast.robot.model import Robot
from thinkfast.sim.controller import ServoConfig, SimController, servo_for

AMPLITUDE = np.array([0.6, 0.5, 0.5, 1.0, 0.8, 1.0])  # rad, excursion about home per joint
# each: out and back. Hard moves last: the servo model may not settle after them (a sustained
# oscillation of a joint driven well beyond its acceleration limit), and the gentle ones must
# be the majority of motion segments for the lag.
PATTERN = ("gentle", "gentle", "gentle", "gentle", "hard", "hard")
CLOSE_WAIT = 60.0  # s: an offline record may wait for its writer (a loaded host), not be cut


def servo_lag(servo: ServoConfig) -> float:
    """Ramp-tracking lag of the servo model [s]: transport delay plus the reference low pass."""
    return servo.delay + 1.0 / (2.0 * math.pi * servo.lowpass_hz)


def excitation(
    robot: Robot, dt: float, hard: float = 1.6, rest: float = 0.3
) -> tuple[np.ndarray, np.ndarray]:
    """Commanded positions [rad] and velocities [rad/s] (N, 6) on a ``dt`` grid (see module)."""
    home = np.asarray(robot.home, dtype=float)
    amp = np.minimum(AMPLITUDE, 0.8 * np.minimum(robot.q_upper - home, home - robot.q_lower))
    otg, inp, out = Ruckig(6, dt), InputParameter(6), OutputParameter(6)
    inp.current_position = list(home)
    inp.current_velocity = [0.0] * 6
    inp.current_acceleration = [0.0] * 6
    inp.synchronization = Synchronization.No  # every joint at its own limits
    qs, qds = [home.copy()], [np.zeros(6)]
    hold = int(round(rest / dt))
    for k, kind in enumerate(PATTERN):
        scale_v, scale_a = (0.5, 0.5) if kind == "gentle" else (0.9, hard)
        sign = 1.0 if k % 2 == 0 else -1.0
        for target in (home + sign * amp, home):
            inp.target_position = list(target)
            inp.target_velocity = [0.0] * 6
            inp.target_acceleration = [0.0] * 6
            inp.max_velocity = list(scale_v * robot.v_max)
            inp.max_acceleration = list(scale_a * robot.a_max)
            inp.max_jerk = list(scale_a * robot.j_max)
            res = Result.Working
            while res == Result.Working:
                res = otg.update(inp, out)
                qs.append(np.array(out.new_position))
                qds.append(np.array(out.new_velocity))
                out.pass_to_input(inp)
            qs.extend([qs[-1]] * hold)
            qds.extend([np.zeros(6)] * hold)
    return np.array(qs), np.array(qds)


def simulate_dynamics_record(
    path: str | Path,
    robot: Robot,
    servo: ServoConfig,
    seed: int,
    *,
    hard: float = 1.6,
    feedback_noise: float = 1e-5,
    t0: float = 1.7e9,
    speed_scale: float = 1.0,
    stalls: float = 0.0,
) -> int:
    """Play :func:`excitation` through a :class:`SimController` and record every exchange.

    Args:
        path: flight record to write (HDF5, created or truncated).
        robot: the arm (home and the limits the excitation scales).
        servo: the simulated controller (the known lag; limits left empty: the robot's).
        seed: randomness of the feedback noise.
        hard: hard moves command this times the robot's acceleration and jerk.
        feedback_noise: std of the measured joints' noise [rad] (ASSUMED encoder-grade).
        t0: time of the first exchange [s] (Unix time).
        speed_scale: the excitation uses the robot's limits times this (as ``thinkfast-run
            --speed-scale`` does).
        stalls: mean receive delay [s] of a loaded host (0: none): the daemon's receive times
            lag the controller's cycles by exponential delays of this mean plus a stall of
            2-15 times it every ~50 cycles, never closer than 0.8 ms (a burst after a stall).

    Returns:
        Rows written.

    Raises:
        RecorderError: the record cannot be written, or rows were dropped.
    """
    rng = np.random.default_rng(seed)
    servo = servo_for(robot, servo)  # the arm's own limits where the servo gives none
    if speed_scale != 1.0:
        robot = dataclasses.replace(
            robot,
            v_max=robot.v_max * speed_scale,
            a_max=robot.a_max * speed_scale,
            j_max=robot.j_max * speed_scale,
        )
    q_cmd, qd_cmd = excitation(robot, servo.dt, hard)
    t_rx = receive_times(t0 + servo.dt * np.arange(len(q_cmd)), stalls, rng)
    sim = SimController(servo, q0=robot.home, max_history=4)
    attrs = {"planner": "calibration", "source": "thinkfast-calib simulate-dynamics",
             "servo": {k: getattr(servo, k) for k in ("delay", "lowpass_hz", "a_max")}}  # fmt: skip
    rec = Recorder(path, attrs)
    try:
        for k in range(len(q_cmd)):
            fb = sim.q + rng.normal(0.0, feedback_noise, 6)
            sim.command(q_cmd[k], qd_cmd[k])
            rec.egm(t_rx[k], k + 1, fb, q_cmd[k], qd_cmd[k], False)
            sim.step(servo.dt)
            if k % 200 == 199:  # let the writer keep up: the pipe holds about 6000 rows
                rec.service()
                time.sleep(0.002)
    finally:
        rec.close(timeout=CLOSE_WAIT)
    st = rec.status()
    if st["state"] != "closed" or st["dropped"]:
        raise RecorderError(f"{path}: simulated record incomplete ({st})")
    return len(q_cmd)


def receive_times(t_ctrl: np.ndarray, stalls: float, rng: np.random.Generator) -> np.ndarray:
    """The daemon's receive times [s] (N,) of packets sent at ``t_ctrl`` [s] (N,) on a host
    whose scheduling delays them (see :func:`simulate_dynamics_record`; 0: no delay)."""
    if stalls <= 0.0:
        return t_ctrl.copy()
    delay = rng.exponential(stalls, len(t_ctrl))
    hit = rng.random(len(t_ctrl)) < 1.0 / 50.0
    delay[hit] += rng.uniform(2.0, 15.0, hit.sum()) * stalls
    out = t_ctrl + delay
    for k in range(1, len(out)):
        out[k] = max(out[k], out[k - 1] + 0.0008)
    return out
