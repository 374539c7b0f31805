"""Action tree files (HDF5, format ``thinkfast-tree`` v3): write, read and verify.

The file describes itself: format name and schema version, the compiler's provenance and full
config as root attributes, one dataset per :class:`~thinkfast.tree.action_tree.ActionTree` array
with ``units``, ``doc`` and a ``sha256`` checksum, and a table of the checksums of every attribute
and dataset (:mod:`thinkfast.tree.manifest`) that every reader verifies before it uses anything.
The layout is documented in ``docs/TREE_FORMAT.md`` and checked by :mod:`thinkfast.tree.layout`;
the fingerprint is :mod:`thinkfast.tree.identity`'s. Every refusal is a
:class:`~thinkfast.errors.TreeFileError` naming the path and the reason.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import secrets
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from thinkfast.errors import TreeFileError
from thinkfast.tree.action_tree import DTYPES, UNITS, ActionTree
from thinkfast.tree.identity import fingerprint_of
from thinkfast.tree.identity import tree_fingerprint as tree_fingerprint  # callers import it here
from thinkfast.tree.layout import (
    DERIVED,
    GROUPS,
    LAYOUT,
    PATHS,
    array_sha256,
    layout_problem,
    shield_dt_problem,
)
from thinkfast.tree.manifest import (
    TABLE,
    Verified,
    entries_of,
    read_attr,
    read_verified,
    table_text,
)

FORMAT = "thinkfast-tree"
SCHEMA_VERSION = 3
# why an older version is refused, and the fix
OLDER = {
    1: "v1 has no shield paths",
    2: "v2 has no checksums of its attributes, and its fingerprint covers the datasets only",
}
JSON_SUFFIX = ".json"  # a meta value stored as a JSON string lives in attribute "<key>.json"
RESERVED_ATTRS = ("format", "schema_version", "fingerprint", "checksums")


def save_tree(tree: ActionTree, path: str | os.PathLike) -> None:
    """Write a tree atomically (temporary file in the same directory, then ``os.replace``).

    Root attributes: ``format``, ``schema_version``, ``created`` (``tree.meta["created"]`` when
    present, else now, ISO 8601 UTC), every ``tree.meta`` entry (str, int, float and bool as they
    are; anything else as JSON in attribute ``"<key>.json"``), ``fingerprint``
    (:func:`tree_fingerprint`) and ``checksums.json``, the sha256 of every attribute and dataset.

    Raises:
        TreeFileError: the tree violates the layout, a meta key is reserved or a value is not
            JSON-able, or the file cannot be written.
    """
    path = Path(path)
    arrays = tree.arrays()
    extra = sorted(set(arrays) - set(PATHS))
    if extra:
        raise TreeFileError(
            f"{path}: array {extra[0]} has no place in tree format v{SCHEMA_VERSION}"
        )
    problem = layout_problem(arrays)
    attrs = _encode_meta(tree.meta, path) if not problem else {}
    problem = problem or shield_dt_problem(tree.meta)
    if problem:
        raise TreeFileError(f"{path}: refusing to write an invalid tree: {problem}")
    if not path.parent.is_dir():
        raise TreeFileError(f"{path}: cannot write: directory {path.parent} does not exist")
    checksums = {name: array_sha256(a) for name, a in arrays.items()}
    root = {
        "format": FORMAT,
        "schema_version": SCHEMA_VERSION,
        "created": attrs.pop("created", _now()),
        **attrs,
        "fingerprint": fingerprint_of(checksums, tree.meta),
    }
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with h5py.File(tmp, "x", track_order=True) as f:
            _write(f, root, _datasets(arrays, checksums))
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError | ValueError | TypeError):
            raise TreeFileError(f"{path}: cannot write ({_first_line(exc)})") from None
        raise


def _datasets(
    arrays: Mapping[str, np.ndarray], checksums: Mapping[str, str]
) -> dict[str, tuple[np.ndarray, dict[str, str]]]:
    """(little-endian array, attributes) of every dataset by path, derived ones last."""
    derived = _derived(arrays)
    items = [(p, arrays[name], UNITS[name], doc, checksums[name]) for name, p, doc in LAYOUT]
    items += [(p, derived[p], u, doc, array_sha256(derived[p])) for p, u, doc in DERIVED]
    return {
        p: (np.asarray(a, dtype=a.dtype.newbyteorder("<")), {"units": u, "doc": doc, "sha256": sha})
        for p, a, u, doc, sha in items
    }


def _write(
    f: h5py.File,
    root: Mapping[str, Any],
    datasets: Mapping[str, tuple[np.ndarray, Mapping[str, str]]],
) -> None:
    groups = {f"/{g}": {"rows": sym, "doc": doc} for g, (sym, doc) in GROUPS.items()}
    for key, value in root.items():
        f.attrs[key] = value
    for g, attrs in groups.items():
        group = f.create_group(g, track_order=True)
        for key, value in attrs.items():
            group.attrs[key] = value
    for p, (a, attrs) in datasets.items():
        ds = f.create_dataset(p, data=a)
        for key, value in attrs.items():
            ds.attrs[key] = value
    f.attrs[TABLE] = table_text(entries_of(root, groups, datasets))


def _derived(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    parent = arrays["node_parent"]
    return {"/edges/parent": parent, "/edges/child": np.arange(len(parent), dtype=np.int32)}


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def _encode_meta(meta: Mapping[str, Any], path: Path) -> dict[str, Any]:
    attrs: dict[str, Any] = {}
    for key, value in meta.items():
        if not isinstance(key, str) or not key or "/" in key:
            raise TreeFileError(f"{path}: meta key {key!r} is not a plain name")
        if key in RESERVED_ATTRS or key.endswith(JSON_SUFFIX):
            raise TreeFileError(f"{path}: meta key {key!r} is reserved by the file format")
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, str | bool | float) or (
            isinstance(value, int) and -(2**63) <= value < 2**63
        ):
            attrs[key] = value
            continue
        try:
            attrs[key + JSON_SUFFIX] = json.dumps(value, default=_json_default)
        except (TypeError, ValueError) as exc:
            raise TreeFileError(f"{path}: meta[{key!r}] is not JSON-able ({exc})") from None
    return attrs


def _json_default(v: Any) -> Any:
    if isinstance(v, np.ndarray | np.generic):
        return v.tolist()
    if isinstance(v, set | frozenset):
        return sorted(v)
    raise TypeError(f"{type(v).__name__} is not JSON-able")


def load_tree(path: str | os.PathLike) -> ActionTree:
    """Read and verify a tree file; the arrays of the returned tree are read-only.

    Raises:
        TreeFileError: the file is missing, not HDF5, truncated, of another format or an unknown
            schema version; an attribute or dataset fails the checksum table (or is missing from
            it or from the file); a dataset has a wrong dtype or shape; the tree violates the
            layout (see :func:`layout_problem`) or its fingerprint attribute does not match.
    """
    return _load(_open(path), path)


def tree_from_bytes(data: bytes, name: str = "<tree bytes>") -> ActionTree:
    """:func:`load_tree` of a tree file's bytes, read in memory (nothing touches the disk);
    ``name`` stands for the path in error messages."""
    if not _has_signature(io.BytesIO(data)):
        raise TreeFileError(f"{name}: not an HDF5 file")
    return _load(_h5(io.BytesIO(data), name), name)


def _load(opened, path) -> ActionTree:
    """Read and verify a tree from an opened file (context manager of :func:`_open` or
    :func:`_h5`)."""
    with opened as f:
        meta, found = _read_verified(f, path)
    fingerprint = meta.pop("fingerprint", None)
    read = {name: _dataset(found, p, DTYPES[name], path) for name, p, _ in LAYOUT}
    derived = {p: _dataset(found, p, np.dtype(np.int32), path)[0] for p, _, _ in DERIVED}
    arrays = {name: a for name, (a, _) in read.items()}
    problem = layout_problem(arrays) or shield_dt_problem(meta)
    if problem:
        raise TreeFileError(f"{path}: invalid tree layout: {problem}")
    for p, want in _derived(arrays).items():
        if not np.array_equal(derived[p], want):
            raise TreeFileError(f"{path}: dataset {p} disagrees with /nodes (file is inconsistent)")
    if fingerprint != fingerprint_of({name: sha for name, (_, sha) in read.items()}, meta):
        raise TreeFileError(
            f"{path}: attribute fingerprint does not match the datasets and identity attributes"
        )
    tree = ActionTree(**arrays, meta=meta)
    return tree.freeze()


def load_meta(path: str | os.PathLike) -> dict[str, Any]:
    """The root attributes (provenance, config) of a tree file, after the same checks of format,
    version and every checksum as :func:`load_tree` (so every dataset is read and hashed); the
    layout and the fingerprint are not checked.

    Raises:
        TreeFileError: missing, non-HDF5 or truncated file, other format, unknown schema version,
            an attribute or dataset that fails the checksum table.
    """
    with _open(path) as f:
        meta, _ = _read_verified(f, path)
    meta.pop("fingerprint", None)
    return meta


@contextlib.contextmanager
def _open(path: str | os.PathLike) -> Iterator[h5py.File]:
    """``h5py.File`` opened read-only; every failure inside becomes a TreeFileError."""
    try:
        if not _has_hdf5_signature(path):
            raise TreeFileError(f"{path}: not an HDF5 file")
    except FileNotFoundError:
        raise TreeFileError(f"{path}: file not found") from None
    except OSError as exc:
        raise TreeFileError(f"{path}: cannot read file ({exc.strerror or exc})") from None
    with _h5(path, path) as f:
        yield f


@contextlib.contextmanager
def _h5(source, name) -> Iterator[h5py.File]:
    """``h5py.File(source)`` read-only; failures become a TreeFileError naming ``name``."""
    try:
        f = h5py.File(source, "r")
    except (OSError, ValueError, RuntimeError) as exc:
        raise _unreadable(name, exc) from None
    try:
        with f:
            yield f
    except (OSError, KeyError, ValueError, RuntimeError, TypeError) as exc:
        raise _unreadable(name, exc) from None


_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _has_hdf5_signature(path: str | os.PathLike) -> bool:
    """The HDF5 signature sits at byte 0, 512, 1024, 2048, ... (after a user block)."""
    with open(path, "rb") as fh:
        return _has_signature(fh)


def _has_signature(fh) -> bool:
    """:func:`_has_hdf5_signature` of an open binary file (or bytes in a ``BytesIO``)."""
    size = fh.seek(0, os.SEEK_END)
    offset = 0
    while offset + len(_SIGNATURE) <= size:
        fh.seek(offset)
        if fh.read(len(_SIGNATURE)) == _SIGNATURE:
            return True
        offset = 512 if offset == 0 else 2 * offset
    return False


def _unreadable(path: str | os.PathLike, exc: BaseException) -> TreeFileError:
    return TreeFileError(f"{path}: truncated or unreadable HDF5 file ({_first_line(exc)})")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__


def _attr(f: h5py.File, key: str, path: str | os.PathLike) -> Any:
    try:
        present = key in f.attrs
    except (OSError, RuntimeError, KeyError, ValueError) as exc:  # HDF5's own metadata checksum
        raise TreeFileError(
            f"{path}: root attributes: unreadable ({_first_line(exc)}) (file is corrupt)"
        ) from None
    if not present:
        raise TreeFileError(f"{path}: missing root attribute {key} (not a thinkfast tree file?)")
    return read_attr(f.attrs, key, f"/@{key}", path)


def _read_verified(f: h5py.File, path: str | os.PathLike) -> tuple[dict[str, Any], Verified]:
    """Format and version checked, then every attribute and dataset against the checksum table:
    the meta (``fingerprint`` still in it; JSON attributes decoded) and every dataset by path."""
    fmt = _attr(f, "format", path)
    if fmt != FORMAT:
        raise TreeFileError(f"{path}: format is {fmt!r}, expected {FORMAT!r}")
    version = _attr(f, "schema_version", path)
    if isinstance(version, bool) or not isinstance(version, int):
        raise TreeFileError(f"{path}: schema_version {version!r} is not an integer")
    if version != SCHEMA_VERSION:
        newer = " (written by a newer thinkfast?)" if version > SCHEMA_VERSION else ""
        if version in OLDER:
            newer = (
                f" ({OLDER[version]}): recompile it with"
                f" `thinkfast-compile tree CONFIG.toml -o {Path(path).name}`"
            )
        raise TreeFileError(
            f"{path}: schema_version {version} is not supported "
            f"(this thinkfast reads {SCHEMA_VERSION}){newer}"
        )
    verified = read_verified(f, path)
    meta: dict[str, Any] = {}
    for key, value in verified.attrs.items():
        if key in ("format", "schema_version"):
            continue
        if key.endswith(JSON_SUFFIX):
            try:
                meta[key.removesuffix(JSON_SUFFIX)] = json.loads(value)
            except (TypeError, ValueError):
                raise TreeFileError(f"{path}: attribute {key} is not valid JSON") from None
        else:
            meta[key] = value
    return meta, verified


def _dataset(
    found: Verified, p: str, dtype: np.dtype, path: str | os.PathLike
) -> tuple[np.ndarray, str]:
    """The verified dataset at ``p`` and its checksum, its dtype checked."""
    if p not in found.arrays:
        raise TreeFileError(f"{path}: missing dataset {p}")
    a = found.arrays[p]
    if a.dtype.newbyteorder("<") != dtype.newbyteorder("<"):
        raise TreeFileError(f"{path}: dataset {p}: dtype {a.dtype}, expected {dtype}")
    return a, found.sha256[p]
