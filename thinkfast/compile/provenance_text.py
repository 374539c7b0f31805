"""The provenance part of ``thinkfast-compile info`` and ``diff``: what a tree was compiled from
(resolved parameters, config text, robot files) and with what (library versions, machine).

Pure functions of ``ActionTree.meta``. Parameters are always the *resolved* ones the runtime reads
(attribute ``parameters``, every key with its default filled in), never the TOML text: a default
left out of one config file and written into another is no difference.
"""

from __future__ import annotations

import json
from typing import Any, NamedTuple

from thinkfast.compile.config import CompileConfig
from thinkfast.config import to_dict
from thinkfast.tree.identity import PATH_PARAMETERS, ROBOT_KEYS, identity_changes, parameters_of

HASHES = ("urdf_sha256", "robot_toml_sha256")
PROVENANCE = ("created", "robot_name", "config_path")  # shown with versions and hashes
SHOWN = 100  # characters of a value shown before "..."


class ProvenanceDiff(NamedTuple):
    """Result of :func:`provenance_diff`.

    Attributes:
        lines: the provenance section of ``diff``.
        inputs_equal: both trees record parameters, and their resolved parameters (robot path
            aside) and robot file hashes are equal: they should be the same tree.
        versions: ``"numpy 1.26.4 -> 2.0.0"`` per differing library version.
        machine: ``"cpu 'A' -> 'B'"`` per differing machine field (dotted, e.g. ``blas.name``).
    """

    lines: list[str]
    inputs_equal: bool
    versions: list[str]
    machine: list[str]


def resolved_parameters(meta: dict[str, Any]) -> dict[str, Any] | None:
    """The tree's compile parameters, flat (``{"tree.max_depth": 3, ...}``): attribute
    ``parameters`` (JSON text or decoded) over the defaults of :class:`CompileConfig`.

    Returns:
        None when the tree records no readable parameters.
    """
    raw = parameters_of(meta)
    if not isinstance(raw, dict):
        return None
    return {**flatten(to_dict(CompileConfig())), **flatten(raw)}


def flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts as one dict of dotted keys."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def versions_of(meta: dict[str, Any]) -> dict[str, Any]:
    """Library versions by name (the ``<name>_version`` attributes)."""
    return {k.removesuffix("_version"): v for k, v in meta.items() if k.endswith("_version")}


def machine_of(meta: dict[str, Any]) -> dict[str, Any]:
    """The ``machine`` record (:func:`thinkfast.machine.machine_info`), flat; {} when absent."""
    machine = json_dict(meta.get("machine"))
    return flatten(machine) if isinstance(machine, dict) else {}


def meta_lines(meta: dict[str, Any]) -> list[str]:
    """``info``'s lines about the meta: parameters, provenance, machine, discards, the rest."""
    params = resolved_parameters(meta)
    lines = [f"parameters (resolved; config sha256 {str(meta.get('config_sha256', '?'))[:12]}):"]
    if params is None:
        lines.append("  none recorded (no readable parameters attribute)")
    lines += [f"  {k} = {fmt(v)}" for k, v in (params or {}).items()]
    prov = [k for k in meta if k in PROVENANCE or k.endswith(("_version", "_sha256"))]
    lines += ["provenance:", *(f"  {k} = {meta[k]}" for k in prov)]
    machine = machine_of(meta)
    lines += ["machine:", *(f"  {k} = {fmt(v)}" for k, v in machine.items())] if machine else []
    discard = [k for k in meta if "discard" in k]
    for k in discard:
        value = json_dict(meta[k])
        items = flatten(value).items() if isinstance(value, dict) else [("", value)]
        lines.append(f"{k}:" + ("" if items else " none"))
        lines += [f"  {name or 'total'} = {fmt(v)}" for name, v in items]
    done = {*prov, *discard, "config_text", "parameters", "machine"}
    rest = [k for k in meta if k not in done]
    if rest:
        lines += ["other attributes:", *(f"  {k} = {fmt(meta[k])}" for k in rest)]
    return lines


def provenance_diff(a: dict[str, Any], b: dict[str, Any]) -> ProvenanceDiff:
    """Compare what two trees were compiled from and with (metas ``a``, ``b``)."""
    pa, pb = resolved_parameters(a), resolved_parameters(b)
    lines = ["provenance:"]
    if pa is None or pb is None:
        lines.append(f"  parameters: not recorded in {_which(pa is None, pb is None)}")
    else:
        keys = _changed_keys(pa, pb)
        note = "(resolved, defaults filled in)"
        count = f"{len(keys)} of {len(set(pa) | set(pb))} differ"
        lines.append(f"  parameters: {count} {note}:" if keys else f"  parameters: equal {note}")
        lines += [f"    {line}" for line in changes(pa, pb, keys)]
        if keys and set(keys) <= set(PATH_PARAMETERS):
            lines.append("    (a path only: the robot is identified by its files' hashes)")
    ca, cb = str(a.get("config_sha256", "?")), str(b.get("config_sha256", "?"))
    if ca == cb:
        lines.append("  config sha256: equal")
    else:
        same = " (text only: comments, layout, defaults written out)" if pa == pb else ""
        lines.append(f"  config sha256: {ca[:12]} -> {cb[:12]}{same}")
    ra, rb = ({k: m.get(k) for k in ROBOT_KEYS} for m in (a, b))
    robot = changes(ra, rb, _changed_keys(ra, rb))
    shown = ", ".join(f"{k.removesuffix('_sha256')} {str(a.get(k))[:12]}" for k in HASHES)
    equal = f"  robot files: equal ({a.get('robot_name', '?')}; {shown})"
    lines += [equal] if not robot else ["  robot files: differ", *(f"    {x}" for x in robot)]
    va, vb = versions_of(a), versions_of(b)
    versions = changes(va, vb, _changed_keys(va, vb), sep=" ")
    lines.append(_section("versions", versions, bool(va), bool(vb)))
    ma, mb = machine_of(a), machine_of(b)
    machine = changes(ma, mb, _changed_keys(ma, mb), sep=" ")
    lines.append(_section("machine", machine, bool(ma), bool(mb)))
    differ = set(identity_changes(a, b))
    inputs = pa is not None and pb is not None and not differ & {"parameters", *HASHES}
    return ProvenanceDiff(lines, inputs, versions, machine)


def _section(name: str, changed: list[str], in_a: bool, in_b: bool) -> str:
    if not in_a or not in_b:
        return f"  {name}: not recorded in {_which(not in_a, not in_b)}"
    return f"  {name}: differ: {', '.join(changed)}" if changed else f"  {name}: equal"


def _which(a: bool, b: bool) -> str:
    return " and ".join(n for n, missing in (("A", a), ("B", b)) if missing)


def _changed_keys(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Keys whose values differ or that only one side has, in ``a``'s order then ``b``'s."""
    keys = [*a, *(k for k in b if k not in a)]
    return [k for k in keys if k not in a or k not in b or a[k] != b[k]]


def defect_line(p: ProvenanceDiff) -> str:
    """The one line ``diff`` prints when equal inputs gave different datasets."""
    why = [f"machine differs: {', '.join(p.machine)}"] if p.machine else []
    why += [f"versions differ: {', '.join(p.versions)}"] if p.versions else []
    if not why:
        why = ["same versions and machine: the compile is not deterministic"]
    return f"defect: equal inputs gave different trees ({'; '.join(why)})"


def changes(a: dict[str, Any], b: dict[str, Any], keys: list[str], sep: str = ": ") -> list[str]:
    """``"key: old -> new"`` for each of ``keys`` (``(not recorded)`` for a side without it)."""
    out = []
    for key in keys:
        va = fmt(a[key]) if key in a else "(not recorded)"
        vb = fmt(b[key]) if key in b else "(not recorded)"
        out.append(f"{key}{sep}{va} -> {vb}")
    return out


def json_dict(v: Any) -> Any:
    """A dict stored as a JSON string (as some writers do) becomes the dict; others unchanged."""
    if isinstance(v, str) and v.startswith("{"):
        try:
            return json.loads(v)
        except ValueError:
            return v
    return v


def fmt(v: Any) -> str:
    """A value for a line of text: strings quoted, at most :data:`SHOWN` characters."""
    text = repr(v) if isinstance(v, str) else str(v)
    return text if len(text) <= SHOWN else text[: SHOWN - 3] + "..."
