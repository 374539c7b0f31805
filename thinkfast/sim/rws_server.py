"""A fake ABB controller that serves the Robot Web Services (RWS 1.0, RobotWare 6) resources
``thinkfast-cell`` uses, with the controller kit's RAPID program simulated behind them.

For tests and rehearsals on loopback, without RobotStudio. It speaks what
``abb_robot_client.rws.RWS`` sends and parses: HTTP/1.1 with digest authentication
(:mod:`thinkfast.sim.rws_http`), ``?json=1`` on every resource, JSON answers in the RWS 1.0
shape, actions as ``POST ...?action=NAME``. The simulated program is the kit's
``ThinkfastEGM.mod`` reduced to its state machine (:meth:`FakeRwsController._step_program`).

The resources served, the program's states and what is not modelled: docs/CELL_RWS.md, "The
fake controller".
"""

from __future__ import annotations

import dataclasses
import threading
import time
from http.server import ThreadingHTTPServer

from thinkfast.sim.rws_http import DigestAuth, make_handler

DEFAULT_USER = "Default User"
DEFAULT_PASSWORD = "robotics"
KIT_VARIABLES = ("tf_start_request", "tf_stop_request", "tf_status")

# the fake's own error codes (not RobotWare's numbers)
ERR_NOT_FOUND = -1073445000
ERR_MOTORS_OFF = -1073445001
ERR_MANUAL = -1073445002
ERR_RUNNING = -1073445003
ERR_BAD_VALUE = -1073445004


@dataclasses.dataclass
class ProgramTiming:
    """Durations of the simulated RAPID program [s] (ASSUMED: short, for tests)."""

    home_time: float = 0.05  # MoveAbsJ to TF_HOME
    ramp_out: float = 0.3  # EGM_RAMP_OUT_TIME of the module
    comm_timeout: float = 0.1  # EGM_COMM_TIMEOUT of the module
    start_delay: float = 0.0  # from a start over RWS to the program's next statement


@dataclasses.dataclass
class Task:
    """One RAPID task as ``rw/rapid/tasks`` lists it."""

    name: str
    motion: bool = True
    active: bool = True
    type_: str = "normal"
    taskstate: str = "linked"
    excstate: str = "ready"


class FakeRwsController:
    """The controller's state, its RAPID program and an HTTP server on loopback.

    Args:
        username, password: the one account the fake accepts (ABB's default user by default).
        timing: durations of the simulated program.
        host: address to bind (loopback).
        port: TCP port (0: a free one; see :attr:`url`).
    """

    def __init__(
        self,
        username: str = DEFAULT_USER,
        password: str = DEFAULT_PASSWORD,
        timing: ProgramTiming | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
    ):
        self.auth = DigestAuth(username, password)
        self.timing = timing or ProgramTiming()
        self.lock = threading.RLock()
        self.ctrlstate = "motoron"  # init motoroff motoron guardstop emergencystop ...
        self.opmode = "AUTO"  # AUTO MANR MANF ...
        self.execstate = "stopped"  # running | stopped
        self.cycle = "forever"
        self.speedratio = 100
        self.tasks = {"T_ROB1": Task("T_ROB1")}
        self.kit_task = "T_ROB1"
        self.variables = {"T_ROB1/tf_start_request": "FALSE", "T_ROB1/tf_stop_request": "FALSE"}
        self.variables["T_ROB1/tf_status"] = '""'
        self.egm_peer = True  # does the daemon answer the EGM session?
        self.pp_at_main = True  # program pointer at main (after load or resetpp)
        self.requests: list[tuple[str, str]] = []  # (method, path) of every authorised request
        self._until = 0.0  # end of the current timed phase (monotonic)
        self._resumes = 0.0  # when a started program runs its next statement (monotonic)
        self._stop = threading.Event()
        self.server = ThreadingHTTPServer((host, port), make_handler(self))
        self.server.daemon_threads = True
        self._threads = [
            threading.Thread(target=self.server.serve_forever, name="fake-rws", daemon=True),
            threading.Thread(target=self._program_loop, name="fake-rapid", daemon=True),
        ]

    @property
    def url(self) -> str:
        """Base URL to give the client, ``http://127.0.0.1:PORT``."""
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}"

    def start(self) -> FakeRwsController:
        """Serve in background threads; returns self."""
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        """Stop serving and the program thread."""
        self._stop.set()
        self.server.shutdown()
        self.server.server_close()
        for t in self._threads:
            t.join(timeout=2.0)

    def __enter__(self) -> FakeRwsController:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ kit variables
    def var(self, name: str) -> str:
        """Value of the kit's persistent ``name`` as RWS shows it (``TRUE``, ``"waiting"``)."""
        with self.lock:
            return self.variables[f"{self.kit_task}/{name}"]

    def status(self) -> str:
        """``tf_status`` without its quotes."""
        return self.var("tf_status").strip('"')

    def _set_var(self, name: str, value: str) -> None:
        self.variables[f"{self.kit_task}/{name}"] = value

    # ------------------------------------------------------------------ simulated program
    def _program_loop(self) -> None:
        while not self._stop.wait(0.002):
            with self.lock:
                self._step_program(time.monotonic())

    def _step_program(self, now: float) -> None:
        """One step of ThinkfastEGM.mod's main loop (the caller holds the lock)."""
        if self.ctrlstate != "motoron" and self.execstate == "running":
            self._halt()  # the controller stops RAPID when the motors go off
        if self.execstate != "running" or now < self._resumes:
            return
        status = self.status()
        if self.pp_at_main:
            self.pp_at_main = False
            self._set_var("tf_status", '"homing"')
            self._until = now + self.timing.home_time
        elif status == "homing" and now >= self._until:
            self._set_var("tf_stop_request", "FALSE")
            self._wait_for_request()
        elif status == "waiting" and self.var("tf_start_request") == "TRUE":
            self._set_var("tf_start_request", "FALSE")
            self._set_var("tf_status", '"session"')
            self._until = now + self.timing.comm_timeout if not self.egm_peer else float("inf")
        elif status == "session" and now >= self._until:
            if self.egm_peer:  # the ramp-out after a stop request has ended
                self._wait_for_request()
            else:  # ERR_UDPUC_COMM: ErrWrite, Stop \NoRegain
                self._set_var("tf_status", '"lost"')
                self._halt()
        elif status == "session" and self.var("tf_stop_request") == "TRUE":
            self._set_var("tf_stop_request", "FALSE")  # the TRAP: EGMStop with ramp-out
            self._until = now + self.timing.ramp_out
        elif status == "lost":  # restarted after a lost session: RETURN, next request
            self._wait_for_request()

    def lose_session(self) -> None:
        """The EGM peer went silent during a session (``ERR_UDPUC_COMM``): the module writes
        "lost" and the program stops, as :meth:`_step_program` does with ``egm_peer=False``."""
        with self.lock:
            if self.status() == "session" and self.execstate == "running":
                self._set_var("tf_status", '"lost"')
                self._halt()

    def _wait_for_request(self) -> None:
        self._set_var("tf_start_request", "FALSE")
        self._set_var("tf_status", '"waiting"')

    def _halt(self) -> None:
        self.execstate = "stopped"
        for t in self.tasks.values():
            if t.excstate == "started":
                t.excstate = "stopped"

    # ------------------------------------------------------------------ resources
    def handle(self, method: str, path: str, query: dict[str, str], form: dict[str, str]):
        """Answer one authorised request: (HTTP status, JSON body or None)."""
        with self.lock:
            self.requests.append((method, path))
            action = query.get("action")
            if method == "GET" and action is None:
                return self._get(path)
            if method == "POST" and action is not None:
                return self._post(path, action, form)
            return _error(400, ERR_NOT_FOUND, f"{method} {path} action={action}: not supported")

    def _get(self, path: str):
        if path == "rw/panel/ctrlstate":
            return _state("pnl-ctrlstate", "ctrlstate", ctrlstate=self.ctrlstate)
        if path == "rw/panel/opmode":
            return _state("pnl-opmode", "opmode", opmode=self.opmode)
        if path == "rw/panel/speedratio":
            return _state("pnl-speedratio", "speedratio", speedratio=str(self.speedratio))
        if path == "rw/rapid/execution":
            return _state(
                "rap-execution", "execution", ctrlexecstate=self.execstate, cycle=self.cycle
            )
        if path == "rw/rapid/tasks":
            return 200, {"_embedded": {"_state": [_task_json(t) for t in self.tasks.values()]}}
        prefix = "rw/rapid/symbol/data/RAPID/"
        if path.startswith(prefix):
            key = path[len(prefix) :]
            if key not in self.variables:
                return _error(400, ERR_NOT_FOUND, f"symbol RAPID/{key} not found")
            return _state("rap-data", "", value=self.variables[key])
        return _error(404, ERR_NOT_FOUND, f"{path}: no such resource")

    def _post(self, path: str, action: str, form: dict[str, str]):
        if path == "rw/rapid/execution":
            return self._execution(action, form)
        if path == "rw/panel/ctrlstate" and action == "setctrlstate":
            wanted = form.get("ctrl-state", "")
            if wanted not in ("motoron", "motoroff"):
                return _error(400, ERR_BAD_VALUE, f"ctrl-state {wanted!r}")
            if wanted == "motoron" and self.opmode != "AUTO":
                return _error(403, ERR_MANUAL, "motors on over RWS needs auto mode")
            self.ctrlstate = wanted
            return 204, None
        if path.startswith("rw/rapid/tasks/") and action in ("activate", "deactivate"):
            task = self.tasks.get(path.rsplit("/", 1)[-1])
            if task is None:
                return _error(400, ERR_NOT_FOUND, f"{path}: no such task")
            task.active = action == "activate"
            return 204, None
        prefix = "rw/rapid/symbol/data/RAPID/"
        if path.startswith(prefix) and action == "set":
            key = path[len(prefix) :]
            if key not in self.variables:
                return _error(400, ERR_NOT_FOUND, f"symbol RAPID/{key} not found")
            value = form.get("value", "")
            if key.endswith(("_request",)) and value not in ("TRUE", "FALSE"):
                return _error(400, ERR_BAD_VALUE, f"{value!r} is not a bool")
            self.variables[key] = value
            return 204, None
        return _error(400, ERR_NOT_FOUND, f"POST {path}?action={action}: not supported")

    def _execution(self, action: str, form: dict[str, str]):
        if action == "start":
            if self.opmode != "AUTO":
                return _error(403, ERR_MANUAL, "start over RWS in manual mode needs RMMP")
            if self.ctrlstate != "motoron":
                return _error(400, ERR_MOTORS_OFF, "cannot start: motors off")
            cycle = form.get("cycle", "asis")
            if cycle != "asis":
                self.cycle = cycle
            self.execstate = "running"
            self._resumes = time.monotonic() + self.timing.start_delay
            for t in self.tasks.values():
                if t.active:
                    t.excstate = "started"
            return 204, None
        if action == "stop":
            self._halt()
            return 204, None
        if action == "resetpp":
            if self.execstate == "running":
                return _error(400, ERR_RUNNING, "resetpp while running")
            self.pp_at_main = True
            for t in self.tasks.values():
                t.excstate = "ready"
            return 204, None
        return _error(400, ERR_NOT_FOUND, f"rw/rapid/execution?action={action}: not supported")


def _state(type_: str, title: str, **fields: str):
    return 200, {"_embedded": {"_state": [{"_type": type_, "_title": title, **fields}]}}


def _error(http: int, code: int, msg: str):
    return http, {"_embedded": {"status": {"code": code, "msg": f"fake-rws: {msg}"}}}


def _task_json(t: Task) -> dict[str, str]:
    return {
        "_type": "rap-task-li",
        "_title": t.name,
        "name": t.name,
        "type": t.type_,
        "taskstate": t.taskstate,
        "excstate": t.excstate,
        "active": "On" if t.active else "Off",
        "motiontask": "TRUE" if t.motion else "FALSE",
    }
