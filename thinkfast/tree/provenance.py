"""Where a tree came from, typed: the one reader of the compile provenance in ``ActionTree.meta``.

The file keeps provenance as root attributes (docs/TREE_FORMAT.md, "Provenance"); the compiler
writes the configuration as the exact TOML text read (``config_text``, for humans and hashes) and
as the resolved parameters (``parameters``, JSON). Code reads the parameters, through this record,
never a key by string, and never the TOML text: the parameters are what the tree's fingerprint
covers (:mod:`thinkfast.tree.identity`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thinkfast.contract.frames import PlanePose
from thinkfast.errors import TreeFileError

DEFAULT_ROBOT = "../robots/irb1600/robot.toml"  # the compile config's default, relative to it


@dataclass(frozen=True)
class Provenance:
    """The compile provenance of one tree.

    Attributes:
        created: ISO 8601 UTC creation time.
        versions: package versions (``thinkfast``, ``ruckig``, ``pinocchio``, ...).
        machine: the compiling machine (:func:`thinkfast.machine.machine_info`; {} when absent).
        config_path: the compile configuration's path when compiled.
        config_text: its exact TOML text; ``config_sha256`` its hash.
        urdf_sha256, robot_toml_sha256: hashes of the robot description used.
        parameters: the resolved compile configuration (every key, defaults filled in).
        shield_dt: sample spacing of the shield paths [s].
    """

    created: str
    versions: dict[str, str]
    machine: dict[str, Any]
    config_path: str
    config_text: str
    config_sha256: str
    urdf_sha256: str
    robot_toml_sha256: str
    parameters: dict[str, Any]
    shield_dt: float

    @classmethod
    def of(cls, meta: dict[str, Any], where: str = "tree") -> Provenance:
        """The provenance in ``meta`` (``ActionTree.meta``).

        Raises:
            TreeFileError: a key is missing or ``parameters`` is not a JSON object (names it).
        """
        try:
            params = meta["parameters"]
            params = json.loads(params) if isinstance(params, str) else params
            if not isinstance(params, dict):
                raise ValueError("not a JSON object")
            machine = meta.get("machine")
            return cls(
                created=str(meta.get("created", "")),
                versions={
                    k.removesuffix("_version"): str(v)
                    for k, v in meta.items()
                    if k.endswith("_version")
                },
                machine=dict(machine) if isinstance(machine, dict) else {},
                config_path=str(meta["config_path"]),
                config_text=str(meta["config_text"]),
                config_sha256=str(meta["config_sha256"]),
                urdf_sha256=str(meta["urdf_sha256"]),
                robot_toml_sha256=str(meta["robot_toml_sha256"]),
                parameters=params,
                shield_dt=float(meta["shield_dt"]),
            )
        except KeyError as exc:
            raise TreeFileError(f"{where}: provenance has no {exc.args[0]!r}") from None
        except (ValueError, TypeError) as exc:
            raise TreeFileError(f"{where}: provenance 'parameters' unreadable ({exc})") from None

    @property
    def eps(self) -> float:
        """Largest primitive duration [s]."""
        return float(self.parameters["tree"]["eps"])

    @property
    def plane_x(self) -> float:
        """The intercept plane ``x = plane_x`` in the ``plane`` frame [m] (``base`` when the
        plane has no pose)."""
        return float(self.parameters["plane"]["distance"])

    @property
    def plane(self) -> PlanePose:
        """The plane's pose in ``base`` (a tree without pose keys: the contract's plane)."""
        return PlanePose.from_dict(self.parameters["plane"])

    @property
    def region(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The protected region on the plane, ``((y_min, y_max), (z_min, z_max))`` [m] in the
        plane's frame: the goal grid's ranges, where the simulated thrower aims."""
        g = self.parameters["goals"]
        return (float(g["y_min"]), float(g["y_max"])), (float(g["z_min"]), float(g["z_max"]))

    @property
    def config_parameters(self) -> dict[str, Any]:
        """The parameters as a compile configuration reads them: without ``home``, which the
        compiler solved and records beside them (:attr:`home`)."""
        return {k: v for k, v in self.parameters.items() if k != "home"}

    @property
    def home(self) -> tuple[float, ...] | None:
        """The home the tree was compiled from when the compiler solved it (``parameters.home``,
        [rad]); None: robot.toml's home (covered by ``robot_toml_sha256``).

        Raises:
            TreeFileError: ``parameters.home`` is not a list of numbers.
        """
        h = self.parameters.get("home")
        if h is None:
            return None
        try:
            return tuple(float(x) for x in h)
        except (TypeError, ValueError):
            raise TreeFileError(f"provenance 'parameters.home' is no joint list: {h!r}") from None

    def robot_toml(self) -> Path | None:
        """robot.toml the tree was compiled for, if it still exists where the config said."""
        rel = self.parameters.get("robot") or DEFAULT_ROBOT
        path = (Path(self.config_path).parent / rel).resolve()
        return path if path.is_file() else None
