"""Action tree files (HDF5, format ``thinkfast-tree`` v2): write, read and verify.

The file describes itself: format name and schema version, the compiler's provenance and full
config as root attributes, one dataset per :class:`~thinkfast.tree.action_tree.ActionTree` array
with ``units``, ``doc`` and a ``sha256`` checksum. The layout is documented in
``docs/TREE_FORMAT.md``. Every refusal is a :class:`~thinkfast.errors.TreeFileError` naming the
path and the reason.
"""

from __future__ import annotations

import contextlib
import hashlib
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
from thinkfast.tree.action_tree import (
    DTYPES,
    EDGE_CUT,
    EDGE_REACHED,
    FIELDS,
    SHAPES,
    UNITS,
    ActionTree,
)

FORMAT = "thinkfast-tree"
SCHEMA_VERSION = 2
SHIELD_DT = "shield_dt"  # meta key (v2, required): sample spacing of the shield paths [s]
# why an older version is refused, and the fix
OLDER = {1: "v1 has no shield paths"}
JSON_SUFFIX = ".json"  # a meta value stored as a JSON string lives in attribute "<key>.json"
RESERVED_ATTRS = ("format", "schema_version", "fingerprint")

# group -> (row count symbol, doc); every dataset of a group has the same first-axis length
GROUPS: dict[str, tuple[str, str]] = {
    "nodes": ("N", "one row per node, breadth-first order, row 0 the root (home at rest)"),
    "edges": ("N", "row i: the primitive into node i from its parent; row 0 is the root's stub"),
    "terminals": ("T", "one row per terminal edge (full primitive to a goal, at rest), by node"),
    "goals": ("G", "one row per reachable goal of the IK grid"),
    "subgoals": ("K", "one row per steering sub-goal"),
    "grid": ("M", "one row per point of the full IK goal grid on the plane"),
}

# (ActionTree array, dataset path, doc); the order is the fingerprint order
# (ActionTree array, dataset path, doc) in fingerprint order: from the one field table
LAYOUT: tuple[tuple[str, str, str], ...] = tuple((f.name, f.path, f.doc) for f in FIELDS)
PATHS = {name: path for name, path, _ in LAYOUT}

# derived convenience datasets, written and checked but not part of the ActionTree
DERIVED: tuple[tuple[str, str, str], ...] = (
    ("/edges/parent", "index", "node the primitive leaves from (= /nodes/parent)"),
    ("/edges/child", "index", "node the primitive ends at (= row index)"),
)


def array_sha256(a: np.ndarray) -> str:
    """Checksum of an array: sha256 of ``"<dtype>:<shape>\\n"`` then its little-endian bytes.

    Args:
        a: any array; it is hashed in C order with little-endian byte order, e.g. the header of
            a float64 array of shape (5, 9) is ``"<f8:5,9\\n"`` (bool: ``"|b1"``).

    Returns:
        64 hex digits.
    """
    le = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
    h = hashlib.sha256(f"{le.dtype.str}:{','.join(map(str, le.shape))}\n".encode("ascii"))
    h.update(le.reshape(-1).view(np.uint8).data)
    return h.hexdigest()


def tree_fingerprint(tree: ActionTree) -> str:
    """Identity of a tree's datasets: sha256 over ``"<name> <array_sha256>\\n"`` in LAYOUT order.

    Two trees have the same fingerprint exactly when all their arrays are identical (``meta`` is
    not included).
    """
    return _fingerprint({name: array_sha256(a) for name, a in tree.arrays().items()})


def _fingerprint(checksums: Mapping[str, str]) -> str:
    h = hashlib.sha256()
    for name, _, _ in LAYOUT:
        h.update(f"{name} {checksums[name]}\n".encode("ascii"))
    return h.hexdigest()


def layout_problem(arrays: Mapping[str, np.ndarray]) -> str | None:
    """First violation of the in-memory layout, or None for a valid tree.

    Checks dtypes, shapes, equal row counts per group, and the index invariants the runtime relies
    on: root first, parents before children, depth non-decreasing, contiguous in-bounds child and
    terminal ranges matching the parent and node columns, indices within their targets.

    Args:
        arrays: every ActionTree array by name (as from :meth:`ActionTree.arrays`).
    """
    for name, path, _ in LAYOUT:
        a = arrays[name]
        if a.dtype.newbyteorder("<") != DTYPES[name].newbyteorder("<"):
            return f"{path} has dtype {a.dtype}, expected {DTYPES[name]}"
        want = SHAPES.get(name, ())
        fits = all(w is None or w == d for w, d in zip(want, a.shape[1:], strict=False))
        if a.ndim != 1 + len(want) or not fits:
            sym = GROUPS[path.split("/")[1]][0]
            shown = ", ".join([sym, *("S" if w is None else str(w) for w in want)])
            return f"{path} has shape {a.shape}, expected ({shown})"
    counts: dict[str, tuple[int, str]] = {}
    for name, path, _ in LAYOUT:
        group = path.split("/")[1]
        n, first = counts.setdefault(group, (len(arrays[name]), path))
        if len(arrays[name]) != n:
            return f"{path} has {len(arrays[name])} rows but {first} has {n}"
    for name in ("edge_shield", "term_shield"):
        if not np.all(np.isfinite(arrays[name])):
            return f"{PATHS[name]} holds a value that is not finite"
    if arrays["edge_shield"].shape[1] < 1:
        return f"{PATHS['edge_shield']} has no samples"
    return _index_problem(arrays)


def _shield_dt_problem(meta: Mapping[str, Any]) -> str | None:
    """The v2 meta key ``shield_dt`` must be a positive finite float."""
    dt = meta.get(SHIELD_DT)
    if isinstance(dt, bool) or not isinstance(dt, int | float) or not 0.0 < dt < np.inf:
        return f"meta {SHIELD_DT} (sample spacing of the shield paths, s) is {dt!r}: need > 0"
    return None


def _index_problem(a: Mapping[str, np.ndarray]) -> str | None:
    parent, depth = a["node_parent"], a["node_depth"]
    n, t, g = len(parent), len(a["term_node"]), len(a["goal_yz"])
    k, m = len(a["subgoal_goal"]), len(a["grid_yz"])
    if n == 0:
        return "no root node (/nodes is empty)"
    if parent[0] != -1 or depth[0] != 0:
        return "row 0 is not a root (/nodes/parent[0] must be -1, /nodes/depth[0] 0)"
    rows = np.arange(n)
    bad = np.flatnonzero((parent[1:] < 0) | (parent[1:] >= rows[1:])) + 1
    if bad.size:
        return f"/nodes/parent[{bad[0]}] = {parent[bad[0]]} is not in 0..{bad[0] - 1}"
    if np.any(np.diff(depth) < 0):
        return f"/nodes/depth decreases at row {np.flatnonzero(np.diff(depth) < 0)[0] + 1}"
    bad = np.flatnonzero(depth[1:] != depth[parent[1:]] + 1) + 1
    if bad.size:
        return f"/nodes/depth[{bad[0]}] is not its parent's depth + 1"
    problem = _range_problem("child", a["child_start"], a["child_count"], parent[1:], 1, n)
    if problem:
        return problem
    if np.any(np.diff(a["term_node"]) < 0):
        return "/terminals/node is not sorted (non-decreasing)"
    if t and (a["term_node"].min() < 0 or a["term_node"].max() >= n):
        return f"/terminals/node holds an index outside 0..{n - 1}"
    problem = _range_problem("term", a["term_start"], a["term_count"], a["term_node"], 0, t)
    if problem:
        return problem
    if not np.all(np.isin(a["edge_kind"], (EDGE_CUT, EDGE_REACHED))):
        return f"/edges/kind holds a value other than {EDGE_CUT} (cut) or {EDGE_REACHED} (reached)"
    for name, lo, hi in (
        ("edge_target", -1, k),
        ("term_goal", 0, g),
        ("subgoal_goal", 0, g),
        ("goal_grid_index", 0, m),
    ):
        v = a[name]
        if v.size and (v.min() < lo or v.max() >= hi):
            return f"{PATHS[name]} holds an index outside {lo}..{hi - 1}"
    return None


def _range_problem(
    kind: str, start: np.ndarray, count: np.ndarray, owner: np.ndarray, first: int, total: int
) -> str | None:
    """Rows ``first + j`` belong to node ``owner[j]``; each node's range must hold exactly them."""
    label = f"/nodes/{kind}_start, /nodes/{kind}_count"
    if np.any((start < 0) | (start > total) | (count < 0) | (count > total - start)):
        return f"{label}: a range is outside 0..{total}"
    if not np.array_equal(np.bincount(owner, minlength=len(start)), count):
        return f"{label}: counts do not match the rows that name the node"
    rows = np.arange(first, first + len(owner))
    own = owner.astype(np.intp)
    bad = np.flatnonzero((rows < start[own]) | (rows >= start[own] + count[own]))
    if bad.size:
        return f"{label}: row {rows[bad[0]]} lies outside the range of node {owner[bad[0]]}"
    return None


def save_tree(tree: ActionTree, path: str | os.PathLike) -> None:
    """Write a tree atomically (temporary file in the same directory, then ``os.replace``).

    Root attributes: ``format``, ``schema_version``, ``created`` (``tree.meta["created"]`` when
    present, else now, ISO 8601 UTC), ``fingerprint`` and every ``tree.meta`` entry (str, int,
    float and bool as they are; anything else as JSON in attribute ``"<key>.json"``).

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
    problem = problem or _shield_dt_problem(tree.meta)
    if problem:
        raise TreeFileError(f"{path}: refusing to write an invalid tree: {problem}")
    checksums = {name: array_sha256(a) for name, a in arrays.items()}
    attrs["fingerprint"] = _fingerprint(checksums)
    if not path.parent.is_dir():
        raise TreeFileError(f"{path}: cannot write: directory {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with h5py.File(tmp, "x", track_order=True) as f:
            _write(f, arrays, checksums, attrs)
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


def _write(
    f: h5py.File,
    arrays: Mapping[str, np.ndarray],
    checksums: Mapping[str, str],
    attrs: Mapping[str, Any],
) -> None:
    f.attrs["format"] = FORMAT
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["created"] = attrs.get("created", _now())
    for key, value in attrs.items():
        if key != "created":
            f.attrs[key] = value
    for group, (sym, doc) in GROUPS.items():
        g = f.create_group(group, track_order=True)
        g.attrs["rows"] = sym
        g.attrs["doc"] = doc
    derived = _derived(arrays)
    items = [(p, arrays[name], UNITS[name], doc, checksums[name]) for name, p, doc in LAYOUT]
    items += [(p, derived[p], u, doc, array_sha256(derived[p])) for p, u, doc in DERIVED]
    for p, a, units, doc, sha in items:
        ds = f.create_dataset(p, data=np.asarray(a, dtype=a.dtype.newbyteorder("<")))
        ds.attrs["units"] = units
        ds.attrs["doc"] = doc
        ds.attrs["sha256"] = sha


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
            schema version, lacks a dataset, has a wrong dtype or shape, fails a checksum or
            violates the layout (see :func:`layout_problem`).
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
        meta = _read_meta(f, path)
        read = {name: _read_dataset(f, p, DTYPES[name], path) for name, p, _ in LAYOUT}
        derived = {p: _read_dataset(f, p, np.dtype(np.int32), path)[0] for p, _, _ in DERIVED}
        fingerprint = _attr(f, "fingerprint", path)
    arrays = {name: a for name, (a, _) in read.items()}
    problem = layout_problem(arrays) or _shield_dt_problem(meta)
    if problem:
        raise TreeFileError(f"{path}: invalid tree layout: {problem}")
    for p, want in _derived(arrays).items():
        if not np.array_equal(derived[p], want):
            raise TreeFileError(f"{path}: dataset {p} disagrees with /nodes (file is inconsistent)")
    if fingerprint != _fingerprint({name: sha for name, (_, sha) in read.items()}):
        raise TreeFileError(f"{path}: attribute fingerprint does not match the datasets")
    tree = ActionTree(**arrays, meta=meta)
    return tree.freeze()


def load_meta(path: str | os.PathLike) -> dict[str, Any]:
    """Read only the root attributes (provenance, config) after checking format and version.

    Cheap: no dataset is read or verified, so use :func:`load_tree` before trusting the arrays.

    Raises:
        TreeFileError: missing, non-HDF5 or truncated file, other format, unknown schema version.
    """
    with _open(path) as f:
        return _read_meta(f, path)


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
    if key not in f.attrs:
        raise TreeFileError(f"{path}: missing root attribute {key} (not a thinkfast tree file?)")
    return _plain(f.attrs[key])


def _read_meta(f: h5py.File, path: str | os.PathLike) -> dict[str, Any]:
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
    meta: dict[str, Any] = {}
    for key in f.attrs:
        if key in RESERVED_ATTRS:
            continue
        value = _plain(f.attrs[key])
        if key.endswith(JSON_SUFFIX):
            try:
                meta[key.removesuffix(JSON_SUFFIX)] = json.loads(value)
            except (TypeError, ValueError):
                raise TreeFileError(f"{path}: attribute {key} is not valid JSON") from None
        else:
            meta[key] = value
    return meta


def _plain(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode("utf-8", errors="replace")
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _read_dataset(
    f: h5py.File, p: str, dtype: np.dtype, path: str | os.PathLike
) -> tuple[np.ndarray, str]:
    """The dataset at ``p`` and its verified checksum."""
    obj = f.get(p)
    if obj is None:
        raise TreeFileError(f"{path}: missing dataset {p}")
    if not isinstance(obj, h5py.Dataset):
        raise TreeFileError(f"{path}: {p} is not a dataset")
    if obj.dtype.newbyteorder("<") != dtype.newbyteorder("<"):
        raise TreeFileError(f"{path}: dataset {p}: dtype {obj.dtype}, expected {dtype}")
    expected = _plain(obj.attrs.get("sha256"))
    if not isinstance(expected, str):
        raise TreeFileError(f"{path}: dataset {p}: missing sha256 attribute")
    a = np.asarray(obj[()])
    if array_sha256(a) != expected:
        raise TreeFileError(f"{path}: dataset {p}: checksum mismatch (file is corrupt)")
    return a, expected
