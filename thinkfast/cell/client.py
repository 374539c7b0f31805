"""The controller kit over Robot Web Services: read the controller's state, start and stop EGM.

Speaks RWS 1.0 (RobotWare 6, IRC5) through ``abb_robot_client.rws.RWS`` (abb-robot-client 0.4.0,
the ``cell`` extra); that library does not speak RobotWare 7's RWS 2.0 (docs/CELL_RWS.md).

The kit's program (``ThinkfastEGM.mod``, generated into each robot folder's ``controller/`` by
``thinkfast-compile kit``) runs in one task (``T_ROB1``): started from main it moves home,
clears ``tf_start_request`` and shows ``tf_status`` "waiting"; ``tf_start_request`` TRUE opens
one EGM session ("session"); ``tf_stop_request`` TRUE ends it with the module's ramp-out.
:class:`Cell` follows that: ``start`` waits for "waiting" before it requests (a request set
while the program is still homing would be cleared and lost), ``stop`` waits for the session to
end before an optional halt.

Every failure is a :class:`~thinkfast.errors.CellError` with one line for a person: the
controller unreachable or silent (:class:`~thinkfast.errors.CellUnreachable`), the password
refused (:class:`~thinkfast.errors.CellAuthError`), the state forbids the command
(:class:`~thinkfast.errors.CellRefused`), or an RWS error with the controller's code. What the
state means to a person: :mod:`thinkfast.cell.state`.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from thinkfast.cell.state import KIT_VARIABLES, CellState, TaskInfo, kit_module, start_blockers
from thinkfast.errors import CellAuthError, CellError, CellRefused, CellUnreachable

DEFAULT_URL = "http://127.0.0.1:80"  # RobotStudio virtual controller (RW6); real: the WAN IP
DEFAULT_USER = "Default User"  # ABB's documented default user of RobotWare 6
DEFAULT_PASSWORD = "robotics"  # ... and its documented default password
DEFAULT_TASK = "T_ROB1"
HTTP_TIMEOUT = 5.0  # [s] per HTTP request (ASSUMED: a controller on the LAN answers in < 1 s)
POLL = 0.05  # [s] between reads while waiting for the program
SETTLE = 0.5  # [s] a new session must hold (ASSUMED: > EGM_COMM_TIMEOUT 0.1 s + EGM set-up)


def check_url(url: str) -> str:
    """The base URL without a trailing slash, or CellError: RWS 1.0 is ``http://HOST[:PORT]``."""
    parts = urlsplit(url)
    if parts.scheme == "https":
        raise CellError(
            f"--url {url}: https is RobotWare 7's RWS 2.0, which abb-robot-client 0.4 does not "
            "speak; RobotWare 6 serves RWS 1.0 on http://HOST[:PORT]"
        )
    if parts.scheme != "http" or not parts.hostname or parts.path.strip("/"):
        raise CellError(f"--url {url}: expected http://HOST[:PORT]")
    return url.rstrip("/")


def _errno_reason(text: str) -> str:
    """``... [Errno 111] Connection refused')`` -> ``connection refused``."""
    m = re.search(r"\[Errno -?\d+\] ([^'\")\]]+)", text)
    return m.group(1).strip().lower() if m else "connection failed"


class Cell:
    """One controller over RWS 1.0, with the kit in ``task``.

    Args:
        url: ``http://HOST[:PORT]`` of the controller (its WAN port, or a virtual controller).
        user, password: an RWS user (RobotWare 6 default: "Default User" / "robotics").
        task: RAPID task holding ThinkfastEGM.mod.
        timeout: per HTTP request [s].
        poll: interval of the reads while waiting for the program [s].
        robot_dir: the robot folder whose kit the controller should hold (``robots/irb1600``),
            for the messages; None: the kit named generically.
    """

    def __init__(
        self,
        url: str = DEFAULT_URL,
        user: str = DEFAULT_USER,
        password: str = DEFAULT_PASSWORD,
        task: str = DEFAULT_TASK,
        timeout: float = HTTP_TIMEOUT,
        poll: float = POLL,
        robot_dir: str | None = None,
    ):
        try:
            from abb_robot_client.rws import RWS, ABBException
            from requests.adapters import HTTPAdapter
        except ImportError as exc:
            raise CellError(
                f"abb-robot-client is not installed ({exc}): pip install 'thinkfast[cell]'"
            ) from None
        self.url = check_url(url)
        self.user = user
        self.task = task
        self.timeout = timeout
        self.poll = poll
        self.kit_module = kit_module(robot_dir)
        self._abb_exception = ABBException
        self.rws = RWS(self.url, user, password)

        class _Timeout(HTTPAdapter):
            """The library passes no timeout: give every request ``timeout`` seconds."""

            def send(self, request, **kwargs):  # noqa: ANN001 (requests' signature)
                if kwargs.get("timeout") is None:
                    kwargs["timeout"] = timeout
                return super().send(request, **kwargs)

        # abb-robot-client 0.4.0 keeps its requests.Session as _session (pinned version)
        self.rws._session.mount("http://", _Timeout(max_retries=0))

    # ------------------------------------------------------------------ errors
    def _call(self, what: str, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` with every library or network failure as one CellError line."""
        import requests

        try:
            return fn(*args)
        except requests.exceptions.Timeout:
            raise CellUnreachable(
                f"{self.url}: no answer within {self.timeout:g} s to {what} (controller on? "
                "right address? RWS answers on the WAN port)"
            ) from None
        except requests.exceptions.ConnectionError as exc:
            raise CellUnreachable(
                f"{self.url}: cannot connect ({_errno_reason(str(exc))}): controller on? right "
                "address and port?"
            ) from None
        except requests.exceptions.RequestException as exc:
            raise CellError(f"{self.url}: {what}: {type(exc).__name__}: {exc}") from None
        except self._abb_exception as exc:
            raise CellError(f"{self.url}: {what}: RWS error {exc.code}: {exc}") from None
        except Exception as exc:  # the library raises bare Exception for HTTP errors
            m = re.search(r"HTTP error (\d+)", str(exc))
            if m and m.group(1) == "401":
                raise CellAuthError(
                    f"{self.url}: authentication failed for user {self.user!r} (HTTP 401): "
                    "check --user and --password"
                ) from None
            if m and m.group(1) == "403":
                raise CellError(
                    f"{self.url}: {what}: forbidden (HTTP 403): user {self.user!r} lacks the "
                    "grant, or the controller wants local or manual-mode privileges"
                ) from None
            raise CellError(f"{self.url}: {what}: {exc}") from None

    # ------------------------------------------------------------------ reading
    def read_kit(self) -> dict[str, str | None]:
        """The kit's variables in ``task`` (None for a symbol the task does not have)."""
        out: dict[str, str | None] = {}
        for name in KIT_VARIABLES:
            try:
                out[name] = self._var(name)
            except CellError as exc:
                if isinstance(exc, CellUnreachable | CellAuthError) or "RWS error" not in str(exc):
                    raise
                out[name] = None
        return out

    def _var(self, name: str) -> str:
        """The kit's variable ``name`` in ``task`` as RWS shows it, without quotes."""
        value = self._call(f"read {self.task}/{name}", self.rws.get_rapid_variable, name, self.task)
        return str(value).strip().strip('"')

    def read_state(self) -> CellState:
        """Controller state, mode, RAPID execution, tasks, speed ratio and the kit's variables."""
        ctrl = self._call("read the controller state", self.rws.get_controller_state)
        opmode = self._call("read the operation mode", self.rws.get_operation_mode)
        execution = self._call("read the RAPID execution state", self.rws.get_execution_state)
        tasks = self._call("read the RAPID tasks", self.rws.get_tasks)
        speed = self._call("read the speed ratio", self.rws.get_speedratio)
        infos = tuple(
            TaskInfo(t.name, t.type_, t.taskstate, t.excstate, bool(t.active), bool(t.motiontask))
            for t in tasks.values()
        )
        kit = (
            self.read_kit()
            if any(t.name == self.task for t in infos)
            else dict.fromkeys(KIT_VARIABLES)
        )
        return CellState(
            url=self.url,
            ctrlstate=str(ctrl),
            opmode=str(opmode),
            execstate=str(execution.ctrlexecstate),
            cycle=str(execution.cycle),
            speedratio=float(speed),
            tasks=infos,
            kit_task=self.task,
            kit=kit,
            kit_module=self.kit_module,
        )

    def _progress(self) -> tuple[str, str | None]:
        """(RAPID execution state, tf_status) for the waiting loops."""
        execution = self._call("read the RAPID execution state", self.rws.get_execution_state)
        return str(execution.ctrlexecstate), self._var("tf_status")

    def _wait_status(self, wanted: set[str], wait: float, what: str, each=None) -> str:
        """Poll until tf_status is in ``wanted``; CellError when RAPID stops or ``wait`` passes.
        ``each(status)`` runs after every poll that has not found it."""
        deadline = time.monotonic() + wait
        while True:
            execstate, status = self._progress()
            if status in wanted:
                return status
            if each is not None:
                each(status)
            if execstate != "running":
                raise CellError(
                    f"RAPID stopped while waiting for {what} (tf_status {status!r}): see the "
                    "controller's event log"
                )
            if time.monotonic() >= deadline:
                raise CellError(
                    f"timed out after {wait:g} s waiting for {what} (tf_status {status!r})"
                )
            time.sleep(self.poll)

    def _request_again(self, status: str) -> None:
        """Set tf_start_request again if the program cleared it without taking it.

        A "waiting" read just after RAPID started from main is the stopped program's, not yet
        overwritten: the request set then is cleared when the module's loop starts. The request
        is read first and tf_status after it: FALSE then "waiting" means the loop cleared it,
        FALSE then "session" that the program took it. (Should a request still be set twice,
        the module clears it before its next wait: never a second session.)"""
        if (
            status == "waiting"
            and self._var("tf_start_request").upper() != "TRUE"
            and self._var("tf_status") == "waiting"
        ):
            self._request("tf_start_request")

    def _request(self, name: str) -> None:
        self._call(f"set {self.task}/{name}", self.rws.set_rapid_variable, name, "TRUE", self.task)

    # ------------------------------------------------------------------ commands
    def start(
        self, resetpp: bool = False, wait: float = 30.0, settle: float = SETTLE, say=print
    ) -> str:
        """Start the kit's program if needed and request one EGM session.

        Refuses (CellRefused, one line naming everything missing) unless the controller is in
        auto mode with the motors on and the task holds the kit. ``resetpp`` moves the program
        pointer to main first (RAPID must be stopped). Waits up to ``wait`` [s] for the program
        to show "waiting", sets tf_start_request (again if the program's loop cleared it: a stale
        "waiting" after a start from main), up to ``wait`` again for "session", and then
        watches the session for ``settle`` [s] (a silent daemon loses it after the module's
        ``\\CommTimeout``).

        Returns:
            The closing line for the operator.
        """
        state = self.read_state()
        blockers = start_blockers(state)
        if blockers:
            raise CellRefused("cannot start: " + "; ".join(blockers))
        if resetpp:
            if state.running:
                raise CellRefused(
                    "--resetpp needs RAPID stopped: run 'thinkfast-cell stop --halt' first"
                )
            self._call("reset the program pointer", self.rws.resetpp)
            say("program pointer reset to main")
        elif state.running and state.status == "session":
            return "an EGM session is already running (tf_status session): nothing to do"
        if not state.running:
            # the library deactivates motion tasks it is not given: keep the active ones
            tasks = sorted({t.name for t in state.tasks if t.motion and t.active} | {self.task})
            self._call("start RAPID", self.rws.start, "asis", tasks)
            say(f"RAPID started ({', '.join(tasks)})")
        status = self._wait_status({"waiting", "session"}, wait, "the program to wait for requests")
        if status == "session":
            return "an EGM session is already running (tf_status session)"
        self._request("tf_start_request")
        say("tf_start_request set")
        status = self._wait_status(
            {"session", "lost"}, wait, "the EGM session to open", self._request_again
        )
        # the session ends on the controller's \CommTimeout when the daemon is silent: watch it
        deadline = time.monotonic() + settle
        while status == "session" and time.monotonic() < deadline:
            time.sleep(self.poll)
            _, status = self._progress()
        if status == "lost":
            raise CellError(
                "the EGM session was lost at once (tf_status lost, RAPID stopped): is "
                "thinkfast-run running and reachable from the controller (UDP 6510)?"
            )
        if status != "session":
            return f"EGM session opened and ended within {settle:g} s (tf_status {status})"
        return f"EGM session running (tf_status session, held {settle:g} s)"

    def stop(self, halt: bool = False, wait: float = 5.0, say=print) -> str:
        """End the EGM session through tf_stop_request; with ``halt`` then stop RAPID.

        The module ends the session with EGMStop (HOLD, its ramp-out time); this waits up to
        ``wait`` [s] for tf_status to leave "session". With ``halt`` RAPID is stopped afterwards,
        also when the session did not end in time (a program stop ends EGM on the controller).

        Returns:
            The closing line for the operator.
        """
        state = self.read_state()
        if state.status is None:
            raise CellRefused(
                f"{self.task} has no tf_status: load {self.kit_module} into {self.task}"
            )
        problem: CellError | None = None
        if state.running and state.status == "session":
            self._request("tf_stop_request")
            say("tf_stop_request set: EGM ramps out")
            try:
                status = self._wait_status(
                    {"waiting", "lost", "homing"}, wait, "the EGM session to end"
                )
                message = f"EGM session ended (tf_status {status})"
            except CellError as exc:
                if not halt:
                    raise
                problem, message = exc, ""
        elif state.running:
            message = f"no EGM session running (tf_status {state.status})"
        else:
            message = f"RAPID is stopped (tf_status {state.status}): no session to end"
        if halt:
            execution = self._call("read the RAPID execution state", self.rws.get_execution_state)
            if execution.ctrlexecstate == "running":
                self._call("stop RAPID", self.rws.stop)
                say("RAPID stopped")
            if problem is not None:
                raise CellError(f"{problem}; RAPID was stopped")
            message += "; RAPID stopped"
        return message
