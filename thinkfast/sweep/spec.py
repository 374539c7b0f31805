"""Parameter sweeps: a grid (or list) of compile and run parameters, every planner, one throw set.

A sweep file (TOML, docs/SWEEPS.md) names a base compile config, an optional base runtime
config, the planners and the throws, and under ``[compile]`` and ``[run]`` the values to try for
dotted keys of those configs. Each combination is a *point*: a tree (compiled from the base
config with the point's compile values) benched with the point's runtime config, exactly as
``thinkfast-sim bench`` would bench it.

Everything a point depends on is hashed into keys, so finished work is found again:

* ``tree_key``: the compile config's values (not its file name or the robot's path), the robot
  files' hashes and the thinkfast version; points that differ only in ``[run]`` share a tree.
* ``point_key``: the tree key, the runtime config's values, the planners, reference and throws.

The results directory (:class:`SweepStore`) keeps trees, one file per finished chunk of throws
and one per finished point; a rerun recomputes only what is missing. This module is pure
bookkeeping; ``thinkfast/sim/cluster.py`` runs the work (in this process or on Dask).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
from pathlib import Path
from typing import Any

from thinkfast import __version__
from thinkfast.compile.config import CompileConfig, check_compile_config
from thinkfast.config import from_dict, include_table, load_toml, spec, to_dict, to_toml
from thinkfast.contract.camera_mode import CameraSetup
from thinkfast.control.config import RunConfig
from thinkfast.errors import ConfigError
from thinkfast.sim.planners import DEFAULT, check_planners


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """The ``[sweep]`` table: what every point shares."""

    compile_config: str = spec(doc="base compile config (TOML), relative to the sweep file")
    run_config: str = spec("", doc="base runtime config (TOML), relative; empty: the defaults")
    planners: tuple[str, ...] = spec(DEFAULT, doc="planners run on every throw (any that "
                                     "thinkfast-sim bench --planners takes)")  # fmt: skip
    reference: str = spec("", doc="planner the others are compared with (empty: as bench)")
    throws: int = spec(200, lo=1, doc="throws per point (the same throws at every point)")
    seed: int = spec(1, lo=0, doc="throw and camera-noise seed")
    mix: str = spec("", doc="kinds of throw, KIND=WEIGHT,... as --mix (empty: default mix)")
    feints: int = spec(-1, lo=-1, doc="feints appended to the throws (-1: a tenth of throws)")
    chunk: int = spec(25, lo=1, doc="throws per task (any value gives the same results)")
    mode: str = spec("grid", choices=("grid", "list"), doc="grid: every combination; list: "
                     "the i-th values of every key together")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Point:
    """One combination of swept values.

    Attributes:
        index: position in the sweep (0-based).
        params: swept dotted key (``compile.tree.eps``, ``run.launch.x``) -> value.
        compile_config: the point's compile config (robot path absolute).
        run_config: the point's runtime config.
        tree_key: hash naming the tree (see the module docstring).
        point_key: hash naming the point's results.
    """

    index: int
    params: dict[str, Any]
    compile_config: CompileConfig
    run_config: RunConfig
    tree_key: str
    point_key: str


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A loaded sweep file: its settings, swept keys, points and throws."""

    path: Path
    settings: SweepSettings
    axes: dict[str, list[Any]]
    points: list[Point]
    robot_path: Path
    robot_hashes: tuple[str, str]  # (URDF sha256, robot.toml sha256)
    throw_config: Any  # ThrowConfig (the mix applied)
    feints: int
    reference: str

    @functools.cached_property
    def throws(self) -> list:
        """The throws of every point, drawn as ``bench --throws --seed --mix --feints`` does
        (on first use)."""
        from thinkfast.sim.throws import sample_throws

        return sample_throws(self.throw_config, self.settings.throws, self.settings.seed,
                             self.feints)  # fmt: skip

    @property
    def chunks(self) -> list[tuple[int, int]]:
        """Throw index ranges ``[start, stop)`` of the tasks of one point."""
        n, c = len(self.throws), self.settings.chunk
        return [(s, min(s + c, n)) for s in range(0, n, c)]


def flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested TOML tables to dotted keys; a non-table value ends a key (``{"a": {"b": 1}}`` ->
    ``{"a.b": 1}``; a quoted ``"a.b"`` key gives the same)."""
    out: dict[str, Any] = {}
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            out.update(flatten(v, key))
        else:
            out[key] = v
    return out


def with_value(data: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A copy of the nested table ``data`` with ``dotted`` (``a.b.c``) set to ``value``."""
    out = dict(data)
    head, _, rest = dotted.partition(".")
    if not rest:
        out[head] = value
        return out
    inner = out.get(head, {})
    out[head] = with_value(inner if isinstance(inner, dict) else {}, rest, value)
    return out


def combinations(axes: dict[str, list[Any]], mode: str) -> list[dict[str, Any]]:
    """The points' values: every combination (``grid``, the last key varying fastest) or the
    i-th value of every key together (``list``; every key has as many values)."""
    keys = list(axes)
    if not keys:
        return [{}]
    if mode == "list":
        return [dict(zip(keys, vals, strict=True)) for vals in zip(*axes.values(), strict=True)]
    return [dict(zip(keys, vals, strict=True)) for vals in itertools.product(*axes.values())]


def _sha(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def tree_key(cfg: CompileConfig, robot_hashes: tuple[str, str]) -> str:
    """Hash of what a compiled tree depends on: the config's values but not where the robot
    files are, the robot files' contents, the thinkfast version."""
    values = to_dict(cfg)
    values.pop("robot")
    return _sha({"compile": values, "robot": list(robot_hashes), "thinkfast": __version__})


def point_key(tree: str, run: RunConfig, settings: SweepSettings, reference: str) -> str:
    """Hash of what a point's results depend on (chunking and scheduling do not count)."""
    s = dataclasses.replace(settings, compile_config="", run_config="", chunk=1, mode="grid")
    return _sha({"tree": tree, "run": to_dict(run), "sweep": to_dict(s), "reference": reference})


def compile_text(cfg: CompileConfig, robot_path: Path) -> str:
    """The compile config file of a point (TOML, the robot as an absolute path)."""
    return to_toml(
        dataclasses.replace(cfg, robot=str(robot_path)), "compile config of a sweep point"
    )


# compile keys that change the cell the throws are aimed at (a sweep keeps one)
CELL_KEYS = ("compile.plane.", "compile.robot", "compile.goals.y_", "compile.goals.z_")


def _axes(table: Any, section: str, source: str) -> dict[str, list[Any]]:
    """``[compile]`` or ``[run]`` as ``section.key -> values`` (each a non-empty array)."""
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise ConfigError(source, section, "expected a table of dotted keys and arrays of values")
    out = {}
    for key, values in flatten(table).items():
        if not isinstance(values, list) or not values:
            raise ConfigError(source, f"{section}.{key}", "expected a non-empty array of values "
                              "to try (a tuple-valued key takes an array of arrays)")  # fmt: skip
        out[f"{section}.{key}"] = values
    return out


def _build_compile(base: dict, values: dict[str, Any], source: str) -> CompileConfig:
    data = base
    for k, v in values.items():
        data = with_value(data, k.removeprefix("compile."), v)
    cfg = from_dict(CompileConfig, data, source, "compile")
    return check_compile_config(cfg, source, "compile")


def _build_run(base: dict, values: dict[str, Any], source: str) -> RunConfig:
    data = base
    for k, v in values.items():
        data = with_value(data, k.removeprefix("run."), v)
    return from_dict(RunConfig, data, source, "run")


def _relative(sweep_path: Path, name: str) -> Path:
    p = Path(name)
    return p if p.is_absolute() else sweep_path.parent / p


def load_sweep(path: str | Path) -> Sweep:
    """Read, validate and expand a sweep file.

    Raises:
        ConfigError: naming the sweep file (or a base config) and the key: unknown table or
            key, a value the compile or runtime config refuses, lists of unequal length in
            ``list`` mode, a reference that is not among the planners.
    """
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.throws import ThrowConfig, aimed_at

    path = Path(path)
    src = str(path)
    data = load_toml(path)
    unknown = sorted(set(data) - {"sweep", "compile", "run"})
    if unknown:
        raise ConfigError(src, unknown[0], "unknown table (valid: sweep, compile, run)")
    if "sweep" not in data:
        raise ConfigError(src, "sweep", "missing [sweep] table (compile_config is required)")
    settings = from_dict(SweepSettings, data["sweep"], src, "sweep")
    check_planners(settings.planners, src, "sweep.planners")
    reference = settings.reference or ("tree" if "tree" in settings.planners
                                       else settings.planners[0])  # fmt: skip
    if reference not in settings.planners:
        raise ConfigError(src, "sweep.reference", f"{reference!r} is not one of the planners")

    base_path = _relative(path, settings.compile_config)
    base_compile = load_toml(base_path)
    base_cfg = from_dict(CompileConfig, base_compile, str(base_path))
    robot_path = (base_path.parent / base_cfg.robot).resolve()
    base_compile = with_value(base_compile, "robot", str(robot_path))
    if settings.run_config:
        run_path = _relative(path, settings.run_config)
        base_run = include_table(load_toml(run_path), run_path, "camera_file", "camera",
                                 CameraSetup)  # fmt: skip
        from_dict(RunConfig, base_run, str(run_path))  # its own errors name its own file
    else:
        base_run = {}

    axes = {**_axes(data.get("compile"), "compile", src), **_axes(data.get("run"), "run", src)}
    for key in axes:  # the points share their throws (paired): one cell per sweep
        if key.startswith(CELL_KEYS):
            raise ConfigError(src, key, "the plane, the region and the robot are the cell: every "
                              "point flies the same throws at it, so a sweep keeps one cell "
                              "(sweep each cell's compile config apart)")  # fmt: skip
    for key, values in axes.items():  # one value at a time: the error names the key
        for v in values:
            if key.startswith("compile."):
                _build_compile(base_compile, {key: v}, src)
            else:
                _build_run(base_run, {key: v}, src)
    if settings.mode == "list" and len({len(v) for v in axes.values()}) > 1:
        sizes = ", ".join(f"{k} {len(v)}" for k, v in axes.items())
        raise ConfigError(src, "sweep.mode", f"list mode needs as many values per key ({sizes})")

    robot = load_robot(robot_path)
    hashes = (robot.urdf_sha256, robot.toml_sha256)
    points = []
    for i, values in enumerate(combinations(axes, settings.mode)):
        ccfg = _build_compile(base_compile, {k: v for k, v in values.items()
                                             if k.startswith("compile.")}, src)  # fmt: skip
        rcfg = _build_run(base_run, {k: v for k, v in values.items() if k.startswith("run.")}, src)
        tk = tree_key(ccfg, hashes)
        points.append(Point(i, values, ccfg, rcfg, tk, point_key(tk, rcfg, settings, reference)))

    # the throws aim at the cell's plane and region, as bench --tree does
    throw_cfg = aimed_at(ThrowConfig(), base_cfg.plane.distance, *base_cfg.goals.region())
    if settings.mix:
        from thinkfast.sim.thrower import parse_mix

        mix = parse_mix(settings.mix, f"{src}: sweep.mix")
        throw_cfg = dataclasses.replace(
            throw_cfg, thrower=dataclasses.replace(throw_cfg.thrower, mix=mix)
        )
    feints = settings.throws // 10 if settings.feints == -1 else settings.feints
    return Sweep(path, settings, axes, points, robot_path, hashes, throw_cfg, feints, reference)
