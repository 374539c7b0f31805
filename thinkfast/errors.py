"""One exception tree for the whole project.

The compiler and loaders raise these; command-line edges print ``str(error)`` as one line on
stderr and exit non-zero. The real-time loop never lets them escape.
"""

from __future__ import annotations


class ThinkfastError(Exception):
    """Base class of every error thinkfast raises on purpose."""


class ConfigError(ThinkfastError):
    """A configuration file is missing, unreadable or holds an invalid value.

    Args:
        source: file (or other origin) of the configuration.
        key: dotted key of the offending value, or None for file-level problems.
        problem: what is wrong, written for a person.
    """

    def __init__(self, source: str, key: str | None, problem: str):
        self.source = str(source)
        self.key = key
        self.problem = problem
        where = f"{self.source}: {key}" if key else self.source
        super().__init__(f"{where}: {problem}")


class RobotModelError(ThinkfastError):
    """The robot description (URDF or robot.toml) cannot be used."""


class NoSolutionError(ThinkfastError):
    """A numerical problem (IK, steering) has no acceptable solution."""


class TreeFileError(ThinkfastError):
    """A tree file is refused: the message names the path and the reason."""


class RecorderError(ThinkfastError):
    """The flight recorder cannot record to the path it was given (checked at start-up)."""


class RecordFileError(ThinkfastError):
    """A flight record file is refused: the message names the path and the reason."""


class CellError(ThinkfastError):
    """The robot controller (over Robot Web Services) cannot do what ``thinkfast-cell`` asked."""


class CellUnreachable(CellError):
    """No HTTP answer from the controller: wrong URL, controller off, network or firewall."""


class CellAuthError(CellError):
    """The controller refused the user name or password (HTTP 401)."""


class CellRefused(CellError):
    """The controller's state forbids the command (manual mode, motors off, kit not loaded)."""


class CalibRecordError(ThinkfastError):
    """A calibration record is refused: the message names the path and the reason."""
