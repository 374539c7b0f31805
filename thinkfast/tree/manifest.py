"""The checksum table of a tree file: the sha256 of every attribute and every dataset.

The writer lists, in the root attribute ``checksums.json``, every attribute of the root, of every
group and of every dataset, and every dataset, by key (``/@created``, ``/nodes@rows``,
``/nodes/q@units``, ``/nodes/q``), with :func:`~thinkfast.tree.identity.value_sha256` or
:func:`~thinkfast.tree.layout.array_sha256` of the value written; the table carries the sha256 of
its own entries. :func:`read_verified` is every reader's first step after the format and version:
it refuses a file whose table is missing or damaged, that lacks something the table lists or holds
something it does not, or whose value fails its checksum, naming the attribute or dataset.
docs/TREE_FORMAT.md, "Checksums".
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from typing import Any, NamedTuple

import h5py
import numpy as np

from thinkfast.errors import TreeFileError
from thinkfast.tree.identity import value_sha256
from thinkfast.tree.layout import array_sha256

TABLE = "checksums.json"  # root attribute: {"entries": {key: sha256}, "sha256": of the entries}
CORRUPT = "(file is corrupt)"


class Verified(NamedTuple):
    """What :func:`read_verified` read, every value checked against the table.

    Attributes:
        attrs: root attributes by name (decoded scalars), the table itself left out.
        arrays: every dataset by path (``/nodes/q``), as stored.
        sha256: their verified :func:`~thinkfast.tree.layout.array_sha256` by path.
    """

    attrs: dict[str, Any]
    arrays: dict[str, np.ndarray]
    sha256: dict[str, str]


def attr_key(obj: str, name: str) -> str:
    """Table key of attribute ``name`` of the object at ``obj`` (``"/"``: the root)."""
    return f"/@{name}" if obj == "/" else f"{obj}@{name}"


def label(key: str) -> str:
    """How messages name a table key: ``attribute created``, ``attribute /nodes/q@units``,
    ``dataset /nodes/q``."""
    if key.startswith("/@"):
        return f"attribute {key[2:]}"
    return f"attribute {key}" if "@" in key else f"dataset {key}"


def entries_of(
    root: Mapping[str, Any],
    groups: Mapping[str, Mapping[str, Any]],
    datasets: Mapping[str, tuple[np.ndarray, Mapping[str, Any]]],
) -> dict[str, str]:
    """The table's entries for what a writer is about to write.

    Args:
        root: root attributes by name (scalars), the table excluded.
        groups: attributes by group path (``/nodes``).
        datasets: (array, attributes) by dataset path.
    """
    out = {attr_key("/", k): value_sha256(v) for k, v in root.items()}
    for g, attrs in groups.items():
        out.update({attr_key(g, k): value_sha256(v) for k, v in attrs.items()})
    for p, (a, attrs) in datasets.items():
        out[p] = array_sha256(a)
        out.update({attr_key(p, k): value_sha256(v) for k, v in attrs.items()})
    return out


def table_text(entries: Mapping[str, str]) -> str:
    """The value of attribute ``checksums.json``: compact JSON, keys sorted, with the sha256 of
    :func:`canonical` entries."""
    table = {"entries": dict(sorted(entries.items())), "sha256": _sha(canonical(entries))}
    return json.dumps(table, separators=(",", ":"))


def canonical(entries: Mapping[str, str]) -> str:
    """The entries as hashed: JSON, keys sorted, no spaces."""
    return json.dumps(dict(entries), sort_keys=True, separators=(",", ":"))


def read_verified(f: h5py.File, path: str | os.PathLike) -> Verified:
    """Every attribute and dataset of ``f``, each checked against the checksum table.

    Raises:
        TreeFileError: ``<path>: <what>: <reason>``: the table is missing, unreadable or fails
            its own checksum; a dataset or attribute it lists is missing; one it does not list
            is present; a value fails its checksum or cannot be read.
    """
    root = f.attrs
    names = attr_names(root, "/", path)
    entries = _table(root, TABLE in names, path)
    seen: set[str] = set()

    def checked(attrs: h5py.AttributeManager, obj: str, name: str) -> Any:
        """One attribute, read and checked as soon as it is read (damage stops the reading)."""
        key = attr_key(obj, name)
        value = read_attr(attrs, name, key, path)
        _check(entries, key, _value_sha(value), path)
        seen.add(key)
        return value

    attrs = {n: checked(root, "/", n) for n in names if n != TABLE}
    arrays: dict[str, np.ndarray] = {}
    sums: dict[str, str] = {}
    objects: list[tuple[str, h5py.Group | h5py.Dataset]] = []
    f.visititems(lambda name, obj: objects.append(("/" + name, obj)))
    for name, obj in objects:
        manager = obj.attrs
        for n in attr_names(manager, name, path):
            checked(manager, name, n)
        if isinstance(obj, h5py.Dataset):
            arrays[name] = np.asarray(obj[()])
            sums[name] = array_sha256(arrays[name])
            _check(entries, name, sums[name], path)
            seen.add(name)
    for key in sorted(entries, key=lambda k: "@" in k):  # a missing dataset before its attributes
        if key not in seen:
            raise TreeFileError(f"{path}: missing {label(key)}")
    return Verified(attrs, arrays, sums)


def _check(entries: Mapping[str, str], key: str, sha: str | None, path: str | os.PathLike) -> None:
    if key not in entries:
        raise TreeFileError(
            f"{path}: {label(key)} is not in the checksum table (added after writing?)"
        )
    if sha != entries[key]:
        raise TreeFileError(f"{path}: {label(key)}: checksum mismatch {CORRUPT}")


def read_attr(attrs: h5py.AttributeManager, name: str, key: str, path: str | os.PathLike) -> Any:
    """Attribute ``name`` (of an object's ``attrs``) as a plain Python value; a failure names
    it by its table key ``key``."""
    try:
        return plain(attrs[name])
    except (OSError, ValueError, TypeError, KeyError, RuntimeError) as exc:
        raise TreeFileError(f"{path}: {label(key)}: unreadable ({_why(exc)}) {CORRUPT}") from None


def attr_names(attrs: h5py.AttributeManager, obj: str, path: str | os.PathLike) -> list[str]:
    """The attribute names of the object at ``obj``; a failure (HDF5's own metadata checksum
    of where it keeps them) names the object."""
    try:
        return list(attrs)
    except (OSError, ValueError, TypeError, KeyError, RuntimeError) as exc:
        where = "root attributes" if obj == "/" else f"attributes of {obj}"
        raise TreeFileError(f"{path}: {where}: unreadable ({_why(exc)}) {CORRUPT}") from None


def plain(v: Any) -> Any:
    """An h5py attribute value as str, int, float, bool or list."""
    if isinstance(v, bytes):
        return v.decode("utf-8", errors="replace")
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _table(root: h5py.AttributeManager, present: bool, path: str | os.PathLike) -> dict[str, str]:
    if not present:
        raise TreeFileError(
            f"{path}: missing root attribute {TABLE} (the checksums of every attribute and "
            "dataset) (file is corrupt)"
        )
    text = read_attr(root, TABLE, attr_key("/", TABLE), path)
    try:
        table = json.loads(text)
        entries, sha = table["entries"], table["sha256"]
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in entries.items()):
            raise ValueError("entries are not strings")
    except (TypeError, ValueError, KeyError, AttributeError):
        raise TreeFileError(f"{path}: attribute {TABLE}: not a checksum table {CORRUPT}") from None
    if sha != _sha(canonical(entries)):
        raise TreeFileError(f"{path}: attribute {TABLE}: checksum mismatch {CORRUPT}")
    return entries


def _value_sha(value: Any) -> str | None:
    try:
        return value_sha256(value)
    except (TypeError, OverflowError):
        return None  # an array or other kind of value where the writer wrote a scalar


def _why(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
