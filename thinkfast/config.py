"""TOML configuration into frozen dataclasses, validated at the edge.

Each stage declares one frozen dataclass. Fields carry their constraints in ``field(metadata=...)``
through :func:`spec`; :func:`from_dict` checks unknown keys, types, shapes and ranges and raises a
:class:`~thinkfast.errors.ConfigError` naming the dotted key. Past this module nothing reads files.

A table in a file overrides only the keys it names: every other key keeps the default of the
enclosing config, i.e. the value a default-constructed top-level config holds (a nested field may
default to an instance that differs from its class's own defaults, e.g. ``RunConfig.filter``).
An array of tables is a value, not an override: each element starts from its class defaults.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from thinkfast.errors import ConfigError

T = TypeVar("T")


def spec(
    default: Any = dataclasses.MISSING,
    *,
    doc: str = "",
    unit: str = "",
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    length: int | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """A dataclass field with validation metadata.

    Args:
        default: default value (omit for a required key). Tuples are fine: configs are frozen.
        doc: one-line meaning, shown in errors and docs.
        unit: SI unit of the value.
        lo, hi: inclusive bounds for numbers (each element of a sequence); ``lo_open`` makes the
            lower bound strict (e.g. a duration that must be > 0).
        length: exact length for a tuple value.
        choices: allowed strings.
    """
    meta = dict(doc=doc, unit=unit, lo=lo, hi=hi, lo_open=lo_open, length=length, choices=choices)
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning every failure into a one-line :class:`ConfigError`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(path), None, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), None, f"cannot read file ({exc})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(path), None, f"invalid TOML ({exc})") from None


def include_table(
    data: dict[str, Any], source: str | Path, file_key: str, table: str, cls: type | None = None
) -> dict:
    """``data`` with its ``file_key`` (a path) replaced by the ``[table]`` of the file it names.

    One source of truth for a table several configs share (e.g. the calibrated ``[camera]``
    pose): ``camera_file = "camera.toml"`` in a config reads ``[camera]`` from that file, a
    relative path being relative to the config's own directory. Other tables of the included
    file are ignored. ``data`` without ``file_key`` is returned unchanged. With ``cls`` (the
    table's dataclass) the included table is validated here, so errors name the included file.

    Raises:
        ConfigError: ``file_key`` is not a string, the config also has its own ``[table]``, or
            the included file is unreadable or has no ``[table]`` table (names file and key).
    """
    if file_key not in data:
        return data
    name = data[file_key]
    if not isinstance(name, str) or not name:
        raise ConfigError(str(source), file_key, f"expected a file name, got {_kind(name)}")
    if table in data:
        raise ConfigError(
            str(source), file_key, f"give either {file_key} or a [{table}] table, not both"
        )
    path = Path(name)
    if not path.is_absolute():
        path = Path(source).parent / path
    if not path.is_file():
        raise ConfigError(str(source), file_key, f"{path}: file not found")
    included = load_toml(path)
    if not isinstance(included.get(table), dict):
        raise ConfigError(str(path), table, f"missing [{table}] table (named by {file_key})")
    if cls is not None:
        from_dict(cls, included[table], str(path), table)
    out = {k: v for k, v in data.items() if k != file_key}
    out[table] = included[table]
    return out


def from_dict(cls: type[T], data: Any, source: str, prefix: str = "", base: T | None = None) -> T:
    """Build the frozen dataclass ``cls`` from a TOML table, validating every key.

    Keys ``data`` does not name keep their value in ``base`` (or the class defaults); a nested
    table starts from the enclosing field's default instance, so it overrides only its own keys.

    Args:
        cls: a dataclass whose fields were declared with :func:`spec` (or plain defaults).
        data: the table (dict) read from TOML.
        source: file name, for messages.
        prefix: dotted key of ``data`` inside the file, for messages.
        base: instance of ``cls`` holding the defaults (None: the class's own defaults).

    Raises:
        ConfigError: unknown key, missing key, wrong type, wrong length or out-of-range value.
    """
    if not isinstance(data, dict):
        raise ConfigError(source, prefix or None, f"expected a table, got {_kind(data)}")
    if not prefix and base is None:  # the whole file: a key in the wrong table gets a hint
        try:
            return _from_dict(cls, data, source, prefix, base)
        except ConfigError as exc:
            raise _with_table_hint(exc, cls) from None
    return _from_dict(cls, data, source, prefix, base)


def _from_dict(cls: type[T], data: dict, source: str, prefix: str, base: T | None) -> T:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        key = _join(prefix, unknown[0])
        raise ConfigError(source, key, f"unknown key (valid keys: {', '.join(sorted(fields))})")
    values = {}
    for name, f in fields.items():
        key = _join(prefix, name)
        default = getattr(base, name) if base is not None else _field_default(f)
        if name not in data:
            if default is dataclasses.MISSING:
                raise ConfigError(source, key, "missing required key")
            continue
        values[name] = _convert(hints[name], data[name], f.metadata, source, key, default)
    return dataclasses.replace(base, **values) if base is not None else cls(**values)


def _with_table_hint(exc: ConfigError, root: type) -> ConfigError:
    """``exc`` with ``(NAME is a key of [TABLE])`` added when it is an unknown key that some
    other table of ``root`` has."""
    if not exc.problem.startswith("unknown key") or not exc.key:
        return exc
    name = exc.key.rsplit(".", 1)[-1]
    here = exc.key.rsplit(".", 1)[0] if "." in exc.key else ""
    tables = [t for t in _tables_with(root, name, "") if t != here]
    if not tables:
        return exc
    where = " or ".join("the top level" if not t else f"[{t}]" for t in tables)
    problem = exc.problem.replace("unknown key", f"unknown key here: {name} is a key of {where}", 1)
    return ConfigError(exc.source, exc.key, problem)


def _tables_with(cls: type, name: str, prefix: str) -> list[str]:
    """Dotted tables of the config class ``cls`` (nested dataclasses, arrays of tables) that
    have a key ``name``."""
    out = [prefix] if name in {f.name for f in dataclasses.fields(cls)} else []
    for f_name, tp in typing.get_type_hints(cls).items():
        args = [a for a in typing.get_args(tp) if a is not type(None) and a is not Ellipsis]
        for sub in [tp, *args]:
            if dataclasses.is_dataclass(sub):
                out += _tables_with(sub, name, _join(prefix, f_name))
                break
    return out


def to_dict(obj: Any) -> dict[str, Any]:
    """A frozen config back to plain TOML-able data (tuples become lists)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        return v

    return plain(obj)


def to_toml(obj: Any, title: str = "") -> str:
    """The frozen config ``obj`` as commented TOML that :func:`from_dict` reads back to ``obj``.

    Every key is written with its value in ``obj``, its doc (a comment above it) and its unit
    and bounds (a comment after it), all from the fields' :func:`spec` metadata; a nested config
    becomes a ``[table]`` headed by its class's first docstring line, a tuple of configs an
    array of tables. A key whose value is None (unset) is written commented out.

    Args:
        obj: a config dataclass instance.
        title: comment lines for the top of the file ('' for none).
    """
    lines = [*(f"# {t}" if t else "#" for t in title.splitlines()), ""] if title else []
    _toml_table(obj, "", lines)
    return "\n".join(lines).strip("\n") + "\n"


def _toml_table(obj: Any, prefix: str, lines: list[str]) -> None:
    """Append ``obj``'s keys, then its tables and arrays of tables, to ``lines``."""
    tables, arrays = [], []
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            tables.append((f.name, v))
            continue
        if isinstance(v, tuple) and v and all(dataclasses.is_dataclass(x) for x in v):
            arrays.append((f.name, v))
            continue
        doc = _plain_doc(f.metadata.get("doc", ""))
        lines += [f"# {t}" for t in _wrap(doc, 96)]
        note = _bounds_note(f.metadata)
        text = f"{f.name} = {_toml_value(v)}" if v is not None else f"# {f.name} = (unset)"
        lines.append(f"{text}  # {note}" if note else text)
    for name, v in tables:
        _toml_header(f"[{_join(prefix, name)}]", v, lines)
        _toml_table(v, _join(prefix, name), lines)
    for name, items in arrays:
        for item in items:
            _toml_header(f"[[{_join(prefix, name)}]]", item, lines)
            _toml_table(item, _join(prefix, name), lines)


def _toml_header(header: str, obj: Any, lines: list[str]) -> None:
    doc = (type(obj).__doc__ or "").strip().splitlines()
    first = _plain_doc(doc[0]) if doc else ""
    lines += ["", f"{header}" + (f"  # {first}" if first else "")]


def _plain_doc(text: str) -> str:
    """A docstring line without reStructuredText roles and literals."""
    text = re.sub(r":(func|class|mod|data|meth|attr):", "", text)
    return " ".join(text.replace("``", "").replace("`", "").split())


def _toml_value(v: Any) -> str:
    """One TOML value: strings quoted, numbers as Python writes them, sequences as arrays."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)  # JSON's escapes are TOML's basic-string escapes
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else f"{v:+}"[:4])
    if isinstance(v, int):
        return str(v)
    if isinstance(v, tuple | list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")  # programming error


def _bounds_note(meta: Any) -> str:
    """``unit, bounds, choices`` of a field, e.g. ``s, > 0, <= 0.5``."""
    parts = [meta["unit"]] if meta.get("unit") else []
    if meta.get("lo") is not None:
        parts.append(f"{'>' if meta.get('lo_open') else '>='} {meta['lo']:g}")
    if meta.get("hi") is not None:
        parts.append(f"<= {meta['hi']:g}")
    if meta.get("choices"):
        parts.append("one of " + ", ".join(meta["choices"]))
    return ", ".join(parts)


def _wrap(text: str, width: int) -> list[str]:
    """``text`` split into lines of at most ``width`` characters at spaces."""
    import textwrap

    return textwrap.wrap(" ".join(text.split()), width) if text else []


def _field_default(f: dataclasses.Field) -> Any:
    """The field's default value (MISSING for a required field)."""
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return f.default


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _kind(v: Any) -> str:
    return {dict: "a table", list: "an array", str: "a string", bool: "a boolean"}.get(
        type(v), type(v).__name__
    )


def _convert(tp: Any, v: Any, meta: Any, source: str, key: str, default: Any = None) -> Any:
    """``v`` as type ``tp``; ``default`` is the field's default (the base of a nested table)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if v is None:
            return None
        return _convert(args[0], v, meta, source, key, default)
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, v, source, key, default if isinstance(default, tp) else None)
    if origin is tuple:
        if not isinstance(v, list):
            raise ConfigError(source, key, f"expected an array, got {_kind(v)}")
        args = typing.get_args(tp)
        want = meta.get("length") if meta else None
        if want is not None and len(v) != want:
            raise ConfigError(source, key, f"expected {want} values, got {len(v)}")
        item_t = args[0]
        return tuple(_convert(item_t, x, meta, source, f"{key}[{i}]") for i, x in enumerate(v))
    if tp is bool:
        if not isinstance(v, bool):
            raise ConfigError(source, key, f"expected true or false, got {_kind(v)}")
        return v
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(source, key, f"expected an integer, got {_kind(v)}")
        _check_range(float(v), meta, source, key)
        return v
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ConfigError(source, key, f"expected a number, got {_kind(v)}")
        if not math.isfinite(v):
            raise ConfigError(source, key, f"expected a finite number, got {v}")
        _check_range(float(v), meta, source, key)
        return float(v)
    if tp is str:
        if not isinstance(v, str):
            raise ConfigError(source, key, f"expected a string, got {_kind(v)}")
        choices = meta.get("choices") if meta else None
        if choices and v not in choices:
            raise ConfigError(source, key, f"{v!r} is not one of {', '.join(choices)}")
        return v
    raise TypeError(f"unsupported config type {tp!r} for {key}")  # programming error


def _check_range(v: float, meta: Any, source: str, key: str) -> None:
    if not meta:
        return
    lo, hi = meta.get("lo"), meta.get("hi")
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    problem = None
    if lo is not None:
        if meta.get("lo_open") and not v > lo:
            problem = f"must be > {lo:g}{unit}, got {v:g}"
        elif not meta.get("lo_open") and not v >= lo:
            problem = f"must be >= {lo:g}{unit}, got {v:g}"
    if problem is None and hi is not None and not v <= hi:
        problem = f"must be <= {hi:g}{unit}, got {v:g}"
    if problem is not None:
        raise ConfigError(source, key, problem + _unit_hint(v, meta))


UNIT_SLIPS = {"rad": ("degrees", "deg", math.pi / 180.0), "m": ("millimetres", "mm", 1e-3)}


def _unit_hint(v: float, meta: Any) -> str:
    """`` (degrees? 5 deg = 0.0873 rad)`` when ``v`` is out of range in the field's SI unit
    but in range as the unit people often type instead (degrees for rad, mm for m)."""
    slip = UNIT_SLIPS.get(meta.get("unit", ""))
    if slip is None:
        return ""
    word, short, factor = slip
    x, lo, hi = v * factor, meta.get("lo"), meta.get("hi")
    if (lo is not None and not x >= lo) or (hi is not None and not x <= hi):
        return ""
    return f" ({word}? {v:g} {short} = {x:.4g} {meta['unit']})"
