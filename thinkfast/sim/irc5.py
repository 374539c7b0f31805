"""A simulated IRC5 on one machine: EGM over UDP and Robot Web Services over HTTP, coupled.

``thinkfast-sim controller`` runs it so docs/CELL.md can be rehearsed without RobotStudio: the
RWS side is :class:`~thinkfast.sim.rws_server.FakeRwsController` (motors, operating mode, the
kit's RAPID program ``ThinkfastEGM.mod`` as a state machine, its persistent variables), the EGM
side a :class:`~thinkfast.sim.controller.SimController` (servo model) run by a
:class:`~thinkfast.sim.controller_runner.ControllerRunner`. As on the real controller, ``EgmRobot``
packets flow only while the program is in an EGM session (``tf_status`` "session", started
by ``thinkfast-cell start``), they report the motors and RAPID state RWS shows, and a session
whose sensor stays silent for ``comm_timeout`` is lost (the program stops, "lost").
With throws (:meth:`SimIrc5.throw_in_session`), simulated balls are thrown at the daemon once a
session runs and judged from this arm's motion: a rehearsal to the first simulated block.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from thinkfast.sim.controller import ServoConfig
from thinkfast.sim.controller_runner import ControllerRunner
from thinkfast.sim.realtime import WallClockSim
from thinkfast.sim.rws_server import FakeRwsController, ProgramTiming

log = logging.getLogger("thinkfast.sim.irc5")

# ASSUMED durations of the simulated program for a rehearsal (the kit's module: homing takes
# the MoveAbsJ's time, EGM_RAMP_OUT_TIME 0.5 s, EGM_COMM_TIMEOUT a few seconds)
REHEARSAL = ProgramTiming(home_time=1.0, ramp_out=0.5, comm_timeout=2.0)
# a session is lost after comm_timeout without an answer while the controller sent at least this
# share of that time's cycles: a controller starved by its host (it sent nothing) blames no one
SILENT_SHARE = 0.5
HISTORY = 2500  # joint samples kept, stamped with the wall clock: 10 s at 250 Hz (the judge)


class SimIrc5:
    """The coupled controller (module doc); call :meth:`step` every few ms (or :meth:`run`).

    Args:
        egm_target: ``(host, port)`` of the daemon's EGM socket (the UDP unicast device).
        rws_host, rws_port: where RWS listens (port 0: a free one; see :attr:`url`).
        servo: the arm's servo model.
        q0: joints at start [rad] (n_joints,), default the servo's zero.
        timing: durations of the simulated RAPID program.
    """

    def __init__(
        self,
        egm_target: tuple[str, int],
        rws_host: str = "127.0.0.1",
        rws_port: int = 0,
        servo: ServoConfig = ServoConfig(),
        q0=None,
        timing: ProgramTiming = REHEARSAL,
    ):
        self.target = egm_target
        self.rws = FakeRwsController(timing=timing, host=rws_host, port=rws_port)
        self.rws.execstate = "stopped"
        self.sim = WallClockSim(servo, q0=q0, max_history=HISTORY)
        self.runner: ControllerRunner | None = None
        self._last_reply = (0, 0.0, 0)  # (replies, monotonic time it last changed, sent then)
        self._said: tuple | None = None

    @property
    def url(self) -> str:
        """RWS base URL (``thinkfast-cell --url``)."""
        return self.rws.url

    def start(self) -> SimIrc5:
        self.rws.start()
        return self

    def close(self) -> None:
        self._stop_egm()
        self.rws.close()

    def step(self) -> None:
        """Follow the RWS state: motors and RAPID flags into EGM, the stream on in a session,
        a silent sensor loses the session."""
        rws = self.rws
        with rws.lock:
            motors, running, status = (
                rws.ctrlstate == "motoron",
                rws.execstate == "running",
                rws.status(),
            )
        session = running and status == "session"
        self.sim.motors_on, self.sim.rapid_running, self.sim.mci_running = motors, running, session
        now = time.monotonic()
        if session and self.runner is None:
            self.runner = ControllerRunner(self.sim, self.target, keep_cycle=True).start()
            self._last_reply = (0, now, 0)
        elif not session and self.runner is not None:
            self._stop_egm()
        if self.runner is not None:  # an answer is an answer, late or not (a loaded host)
            replies, sent = self.runner.stats.answered, self.runner.stats.sent
            timeout = rws.timing.comm_timeout
            if replies != self._last_reply[0]:
                self._last_reply = (replies, now, sent)
            elif (
                now - self._last_reply[1] > timeout
                and sent - self._last_reply[2] >= SILENT_SHARE * timeout / self.sim.config.dt
            ):  # the sensor was silent while this controller sent (not: this host starved it)
                log.warning("no EGM answer for %.1f s: session lost", now - self._last_reply[1])
                rws.lose_session()
        said = (motors, rws.opmode, running, status)
        if said != self._said:
            self._said = said
            log.info("motors %s, %s, RAPID %s, tf_status %s", "on" if motors else "off",
                     rws.opmode, "running" if running else "stopped", status or "-")  # fmt: skip

    def _stop_egm(self) -> None:
        if self.runner is not None:
            self.runner.stop()
            self.runner.join(2.0)
            self.runner = None

    def joints(self) -> np.ndarray:
        """The simulated arm's joints [rad] (n_joints,)."""
        return self.sim.q.copy()

    def run(self, stop) -> None:
        """:meth:`step` every 10 ms until ``stop()`` is true."""
        while not stop():
            self.step()
            time.sleep(0.01)

    def throw_in_session(
        self, robot, throws, zenoh_endpoint: str, prefix: str, seed: int, extrinsic, report, stop,
        zenoh_config=None,
    ) -> list:  # fmt: skip
        """Once an EGM session runs and the daemon has answered for a second, throw ``throws``
        at the daemon (detections on ``zenoh_endpoint``, in a session configured by the JSON5
        file ``zenoh_config`` when given: a secured cell's camera node) and judge each from this
        arm's wall-clock history (:func:`~thinkfast.sim.realtime.run_throws`); [] when
        ``stop()`` came first. Runs beside :meth:`run` (another thread)."""
        from thinkfast.sim.realtime import run_throws

        while not stop():
            runner = self.runner
            if runner is not None and runner.stats.answered >= 250:
                return run_throws(robot, throws, self.target, zenoh_endpoint, prefix, seed,
                                  extrinsic, report, controller=(self.sim, runner),
                                  zenoh_config=zenoh_config)  # fmt: skip
            time.sleep(0.05)
        return []
