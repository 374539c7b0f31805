"""The controller kit of a robot, rendered from its robot.toml (``thinkfast-compile kit``).

The kit (docs/EGM_CONTROLLER.md, "Controller kit") is the controller's side of the EGM link:
the RAPID module ``ThinkfastEGM.mod``, the UDP unicast device ``sys_cfg_udpuc.cfg``, the
External Motion Interface Data ``moc_ext_motion_thinkfast.cfg`` and a README. The templates
beside this module (``kit_templates/``) hold everything that is the same for every robot: the
RAPID logic, the EGM arguments of docs/EGM_CONTROLLER.md's table, port 6510, the names
``THINKFAST`` / ``thinkfast``. The robot gives only these (:func:`kit_values`):

- ``TF_HOME``: the home [rad], in degrees with 4 decimals (a value that rounds to zero is ``0``).
  RAPID's ``num`` is a 32-bit float, about 7 significant digits: 4 decimals is what it holds of
  a joint angle; the controller moves home within 5e-5 deg of the home.
- ``EGM_MAX_SPEED_DEV``: the fastest positioning joint's ``max_velocity`` [deg/s], rounded UP
  to an integer (:func:`max_speed_deviation`): EGM caps every joint at it, and a cap below a
  speed the tree plans makes the arm lag the plan (docs/EGM_CONTROLLER.md,
  ``\\MaxSpeedDeviation``). A value within 1e-6 deg/s above an integer (rad/s typed from a
  whole deg/s) counts as that integer. Wrist joints faster than the cap are held to it
  (:func:`capped_joints`; ``thinkfast-compile kit`` says which).
- comments: the robot's name and robot.toml in the headers, the joints of that velocity,
  the longest ``v_max / a_max`` (the stop the ramp-out time is set against).

:func:`controller_kit` is pure: the same robot and folder label give the same bytes.
"""

from __future__ import annotations

import math
import re
from importlib import resources
from pathlib import Path
from string import Template
from typing import NamedTuple

from thinkfast.errors import ConfigError
from thinkfast.robot.model import Robot

KIT_FILES = (
    "ThinkfastEGM.mod",
    "sys_cfg_udpuc.cfg",
    "moc_ext_motion_thinkfast.cfg",
    "README.md",
)
HOME_DECIMALS = 4
SPEED_SLACK = 1e-6  # [deg/s] float noise of a whole deg/s typed in rad/s
_REPO = Path(__file__).resolve().parents[2]
_TEMPLATES = "kit_templates"


def robot_dir_label(toml_path: str | Path) -> str:
    """The robot folder as the kit names it: relative to the repository when inside it
    (``robots/irb1600``), else absolute; never relative to the working directory, so that
    ``--check`` gives the same answer from anywhere."""
    folder = Path(toml_path).resolve().parent
    try:
        return folder.relative_to(_REPO).as_posix()
    except ValueError:
        return folder.as_posix()


def format_joints(indices: list[int]) -> str:
    """0-based joint indices as the comments name them: ``joint 3``, ``joints 1-2``,
    ``joints 1-2, 4``."""
    runs: list[list[int]] = []
    for i in sorted(indices):
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    parts = [f"{r[0] + 1}" if len(r) == 1 else f"{r[0] + 1}-{r[-1] + 1}" for r in runs]
    return ("joint " if len(indices) == 1 else "joints ") + ", ".join(parts)


def rapid_degrees(q: float) -> str:
    """One joint angle [rad] as a RAPID literal in degrees: 4 decimals, ``0`` for zero."""
    text = f"{math.degrees(q):.{HOME_DECIMALS}f}"
    return "0" if float(text) == 0.0 else text


def max_speed_deviation(robot: Robot) -> int:
    """``\\MaxSpeedDeviation`` [deg/s]: the fastest positioning joint's ``max_velocity``,
    rounded up: EGM caps every joint at this one speed, and a cap below a speed the tree plans
    makes the arm lag the plan until the daemon's deviation check brakes (the IRB 1600-6/1.2 at
    the slowest joint's 150 deg/s: docs/EGM_CONTROLLER.md). The daemon itself never commands a
    joint above its own ``max_velocity``."""
    fastest = max(math.degrees(v) for v in robot.v_max[: robot.n_arm])
    return math.ceil(fastest - SPEED_SLACK)


def kit_values(robot: Robot, robot_dir: str | Path, home_source: str | None = None) -> dict:
    """The robot-specific text of the kit, by template placeholder.

    Args:
        robot: the loaded robot (its home, ``v_max`` and ``a_max`` are used).
        robot_dir: the robot folder as the kit names it (:func:`robot_dir_label`).
        home_source: where the home comes from, for the module's comment (default: robot.toml's
            ``home``).

    Raises:
        RobotModelError: the robot has no home (robot.toml gives none).
    """
    toml = f"{Path(robot_dir).as_posix()}/{robot.toml_path.name}"
    home = robot.require_home(f"give {toml} a home (a tree's: thinkfast-compile info TREE)")
    v_deg = [math.degrees(v) for v in robot.v_max[: robot.n_arm]]
    fastest = max(v_deg)
    stops = [f"{v / a:.2f}" for v, a in zip(robot.v_max, robot.a_max, strict=True)]
    longest = max(stops, key=float)
    return {
        "name": robot.name,
        "toml": toml,
        "home_source": home_source or f"{toml} `home`",
        "home_deg": ", ".join(rapid_degrees(float(q)) for q in home),
        "max_speed_dev": str(max_speed_deviation(robot)),
        "v_fastest": f"{round(fastest, 3):g}",
        "v_fastest_joints": format_joints(
            [i for i, v in enumerate(v_deg) if v >= fastest - SPEED_SLACK]
        ),
        "stop_time": longest,
        "stop_joints": format_joints([i for i, s in enumerate(stops) if s == longest]),
    }


def _header(values: dict, suffix: str) -> str:
    """The generated-file notice, as a comment of the file's language."""
    lines = (
        f"GENERATED by `thinkfast-compile kit` from {values['toml']} ({values['name']}):",
        "do not edit by hand; change robot.toml or thinkfast/compile/kit_templates/ and "
        "regenerate.",
    )
    if suffix == ".md":
        return f"<!-- {lines[0]}\n     {lines[1]} -->"
    prefix = {".mod": "    ! ", ".cfg": "# "}[suffix]
    return "\n".join(prefix + line for line in lines)


def controller_kit(
    robot: Robot, robot_dir: str | Path, home_source: str | None = None
) -> dict[str, str]:
    """The controller kit of ``robot``: {file name: text}, in :data:`KIT_FILES` order.

    Args:
        robot: the loaded robot.
        robot_dir: the robot folder as the files name it (:func:`robot_dir_label`), e.g.
            ``robots/irb1600``.
        home_source: see :func:`kit_values`.

    Raises:
        RobotModelError: the robot has no home.
    """
    values = kit_values(robot, robot_dir, home_source)
    folder = resources.files(__package__).joinpath(_TEMPLATES)
    out = {}
    for name in KIT_FILES:
        text = folder.joinpath(name).read_text(encoding="utf-8")
        header = _header(values, Path(name).suffix)
        out[name] = Template(text).substitute(values, header=header)
    return out


def kit_differences(kit: dict[str, str], directory: Path) -> list[str]:
    """The files of ``kit`` that ``directory`` lacks or holds with other bytes, one phrase each."""
    out = []
    for name, text in kit.items():
        path = directory / name
        if not path.is_file():
            out.append(f"{path}: missing")
        elif path.read_bytes() != text.encode("utf-8"):
            out.append(f"{path}: differs from what robot.toml gives")
    return out


def write_kit(kit: dict[str, str], directory: Path) -> list[Path]:
    """Write ``kit`` into ``directory`` (created), LF line ends; returns the paths written."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in kit.items():
        path = directory / name
        path.write_bytes(text.encode("utf-8"))
        paths.append(path)
    return paths


class KitSettings(NamedTuple):
    """What a kit's RAPID module makes the controller do that the daemon depends on."""

    home: tuple[float, ...]  # TF_HOME [rad] (the module holds degrees)
    max_speed_deviation: float  # EGM_MAX_SPEED_DEV [rad/s] (the module holds deg/s)


_TF_HOME = re.compile(r"CONST jointtarget TF_HOME := \[\[([^\]]*)\]")
_SPEED = re.compile(r"CONST num EGM_MAX_SPEED_DEV := ([0-9.eE+-]+);")


def read_kit(directory: Path) -> KitSettings:
    """The home and the EGM speed cap of the kit in ``directory`` (its ThinkfastEGM.mod).

    Raises:
        ConfigError: the module is missing or holds no TF_HOME / EGM_MAX_SPEED_DEV line.
    """
    path = Path(directory) / "ThinkfastEGM.mod"
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        why = f"cannot read the kit's module ({exc.strerror})"
        raise ConfigError(str(path), None, why) from None
    home, speed = _TF_HOME.search(text), _SPEED.search(text)
    if home is None or speed is None:
        missing = "TF_HOME" if home is None else "EGM_MAX_SPEED_DEV"
        raise ConfigError(str(path), missing, "not found: is this a thinkfast controller kit?")
    try:
        deg = [float(x) for x in home.group(1).split(",")]
    except ValueError:
        raise ConfigError(str(path), "TF_HOME", f"not numbers: {home.group(1)!r}") from None
    return KitSettings(tuple(math.radians(x) for x in deg), math.radians(float(speed.group(1))))


def capped_joints(robot: Robot) -> list[int]:
    """Joints whose robot.toml ``max_velocity`` is above the kit's EGM speed cap: the controller
    holds them to the cap, so a plan faster than it lags on them."""
    cap = max_speed_deviation(robot) + SPEED_SLACK
    return [i for i, v in enumerate(robot.v_max) if math.degrees(v) > cap]
