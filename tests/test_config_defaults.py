"""A table in a config file overrides only the keys it names; every other key keeps the default of
the enclosing config (the value a default-constructed top-level config holds)."""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import ROBOT_TOML
from thinkfast.compile.config import CompileConfig, load_compile_config
from thinkfast.config import from_dict, load_toml, to_dict
from thinkfast.control.config import RunConfig, load_run_config
from thinkfast.errors import ConfigError
from thinkfast.perception.config import DetectConfig, load_detect_config
from thinkfast.robot.model import RobotToml
from thinkfast.sim.throws import ThrowConfig
from thinkfast.sim.throwset import FORMAT, VERSION, load_throw_set


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def _toml(doc: dict[str, dict[str, Any]]) -> str:
    """Tables of scalars and arrays as TOML text (all this test writes)."""
    out = []
    for table, keys in doc.items():
        out.append(f"[{table}]")
        out += [f"{k} = {_toml_value(v)}" for k, v in keys.items()]
    return "\n".join(out) + "\n"


def _nudge(v: Any, meta: Any) -> Any:
    """A valid value of the same type that differs from ``v`` (inside the field's bounds)."""
    if isinstance(v, bool):
        return not v
    if isinstance(v, str):
        choices = meta.get("choices")
        return next(c for c in choices if c != v) if choices else v + "x"
    if isinstance(v, tuple):
        return tuple(_nudge(x, meta) for x in v)
    lo, hi = meta.get("lo"), meta.get("hi")
    step = 1 if isinstance(v, int) else max(abs(v) * 0.01, 1e-3)
    up = v + step
    if hi is not None and up > hi:
        up = v - step
    assert lo is None or up > lo or (up == lo and not meta.get("lo_open"))
    return up


def _one_key_cases(cfg: Any) -> Iterator[tuple[str, str, Any, Any]]:
    """(table, key, nudged value, expected config) for every key of every table of ``cfg``."""
    hints = typing.get_type_hints(type(cfg))
    for table in dataclasses.fields(cfg):
        if not dataclasses.is_dataclass(hints[table.name]):
            continue
        sub = getattr(cfg, table.name)
        for f in dataclasses.fields(sub):
            value = _nudge(getattr(sub, f.name), f.metadata)
            want_sub = dataclasses.replace(sub, **{f.name: value})
            yield table.name, f.name, value, dataclasses.replace(cfg, **{table.name: want_sub})


def _check_every_key(tmp_path: Path, default: Any, load: Callable[[Path], Any]) -> int:
    cases = list(_one_key_cases(default))
    for table, key, value, expected in cases:
        path = tmp_path / f"{table}.{key}.toml"
        path.write_text(_toml({table: {key: value}}))
        got = load(path)
        diff = {
            f"{t}.{k}": (getattr(getattr(got, t), k), getattr(getattr(expected, t), k))
            for t in (f.name for f in dataclasses.fields(default))
            if dataclasses.is_dataclass(getattr(default, t))
            for k in (f.name for f in dataclasses.fields(getattr(default, t)))
            if getattr(getattr(got, t), k) != getattr(getattr(expected, t), k)
        }
        assert got == expected, f"[{table}] {key} = {value!r} changed {diff} (got, expected)"
    return len(cases)


def test_run_config_table_naming_one_key_keeps_every_other_run_config_default(tmp_path):
    """For every table and key of RunConfig: a file naming only that key yields RunConfig() with
    just that key changed (e.g. [filter] alpha keeps the stereo noise model and reset_all_axes,
    [safety] dt keeps position_margin 0.005 rad)."""
    n = _check_every_key(tmp_path, RunConfig(), load_run_config)
    assert n == sum(
        len(dataclasses.fields(getattr(RunConfig(), f.name)))
        for f in dataclasses.fields(RunConfig)
        if dataclasses.is_dataclass(getattr(RunConfig(), f.name))
    )
    # The two defaults that differ from their class's own defaults survive a neighbouring key.
    path = tmp_path / "two.toml"
    path.write_text("[filter]\nalpha = 0.99\n[safety]\ndt = 0.004\n")
    cfg = load_run_config(path)
    assert cfg.filter.stereo_depth == 0.0027 and cfg.filter.reset_all_axes
    assert cfg.safety.position_margin == 0.005


def test_compile_config_table_naming_one_key_keeps_every_other_default(tmp_path):
    """Same property for every table and key of the compile configuration."""
    base = CompileConfig(robot=str(ROBOT_TOML))

    def load(path: Path) -> CompileConfig:
        text = path.read_text()
        path.write_text(f'robot = "{ROBOT_TOML}"\n' + text)
        return load_compile_config(path).config

    assert _check_every_key(tmp_path, base, load) > 10


def test_detect_config_table_naming_one_key_keeps_every_other_default(tmp_path):
    """Same property for every table and key of thinkfast-detect's configuration."""
    assert _check_every_key(tmp_path, DetectConfig(), load_detect_config) > 20


def test_throw_set_config_naming_one_key_keeps_every_other_default(tmp_path):
    """A throw-set file's config naming one key keeps every other ThrowConfig default."""
    default = ThrowConfig()
    cases = []
    for f in dataclasses.fields(default):
        v = getattr(default, f.name)
        if dataclasses.is_dataclass(v):  # a nested table: each of its keys alone
            for g in dataclasses.fields(v):
                value = _nudge(getattr(v, g.name), g.metadata)
                want = dataclasses.replace(
                    default, **{f.name: dataclasses.replace(v, **{g.name: value})}
                )
                cases.append(({f.name: {g.name: value}}, want))
        else:
            value = _nudge(v, f.metadata)
            cases.append(({f.name: value}, dataclasses.replace(default, **{f.name: value})))
    for config, want in cases:
        doc = {"format": FORMAT, "version": VERSION, "config": config}
        path = tmp_path / "set.json"
        path.write_text(json.dumps(doc))
        assert load_throw_set(path).config == want


def test_robot_toml_cell_objects_take_their_class_defaults():
    """An array of tables is a value: each cell object naming no rpy gets CellObject's default."""
    cfg = from_dict(RobotToml, load_toml(ROBOT_TOML), str(ROBOT_TOML))
    floor = next(c for c in cfg.cell if c.name == "floor")
    assert floor.rpy == (0.0, 0.0, 0.0) and floor.xyz == (0.0, 0.0, -0.05)


def test_to_dict_round_trip_of_every_default_config():
    """Writing a default config out and reading it back changes nothing."""
    for cfg in (RunConfig(), CompileConfig(), DetectConfig(), ThrowConfig()):
        assert from_dict(type(cfg), to_dict(cfg), "x.toml") == cfg


@pytest.mark.parametrize("cls", [RunConfig, CompileConfig, DetectConfig])
def test_nested_override_still_validates_the_named_key(tmp_path, cls):
    """Starting from the enclosing default does not skip validation of the named key."""
    table = next(f.name for f in dataclasses.fields(cls) if dataclasses.is_dataclass(f.default))
    path = tmp_path / "bad.toml"
    path.write_text(f"[{table}]\nno_such_key = 1\n")
    loaders = {RunConfig: load_run_config, CompileConfig: load_compile_config}
    loaders[DetectConfig] = load_detect_config
    with pytest.raises(ConfigError, match=f"{table}.no_such_key: unknown key"):
        loaders[cls](path)
