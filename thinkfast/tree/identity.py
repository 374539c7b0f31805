"""A tree's identity (its fingerprint) and the checksum of a scalar attribute value, without HDF5.

The fingerprint names what a tree *is*: the same configuration and robot compiled on any machine
on any day give the same fingerprint, and any change to a dataset or to an attribute the runtime
reads its settings from gives another. It covers every dataset (:func:`array_sha256`, in
``LAYOUT`` order) and the root attributes of :data:`IDENTITY_KEYS`; it leaves out what only says
how, when and where the tree was made (``created``, ``config_path``, ``config_text`` and its
``config_sha256``, ``jobs``, ``compile_seconds``, library versions, ``machine``, discard counts).
docs/TREE_FORMAT.md, "Fingerprint", gives the exact bytes hashed.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from thinkfast.tree.action_tree import ActionTree
from thinkfast.tree.layout import LAYOUT, array_sha256

# root attributes that define the tree and that the runtime reads, in fingerprint order
IDENTITY_KEYS = (
    "parameters",  # the resolved compile configuration (JSON), without PATH_PARAMETERS
    "robot_name",
    "urdf_sha256",
    "robot_toml_sha256",
    "plane_distance",
    "shield_radius",
    "shield_dt",
)
ROBOT_KEYS = ("robot_name", "urdf_sha256", "robot_toml_sha256")
# parameters that name a file, not a value: the robot is identified by its files' hashes
PATH_PARAMETERS = ("robot",)
ABSENT = "absent"  # the fingerprint's word for an identity key the meta does not hold


def value_sha256(value: Any) -> str:
    """Checksum of a scalar attribute value as the file stores it.

    A string hashes ``"str\\n"`` then its UTF-8 bytes; a bool, an int and a float hash as the 0-d
    arrays of ``|b1``, ``<i8`` and ``<f8`` (:func:`array_sha256`, e.g. ``"<f8:\\n"`` then the 8
    bytes).

    Raises:
        TypeError: ``value`` is not a str, bool, int or float (or numpy scalar of one).
        OverflowError: an int outside int64.
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, str):
        h = hashlib.sha256(b"str\n")
        h.update(value.encode("utf-8", errors="surrogateescape"))
        return h.hexdigest()
    if isinstance(value, bool):
        return array_sha256(np.asarray(value, dtype=np.bool_))
    if isinstance(value, int):
        if not -(2**63) <= value < 2**63:
            raise OverflowError(f"{value} does not fit in int64")
        return array_sha256(np.asarray(value, dtype=np.int64))
    if isinstance(value, float):
        return array_sha256(np.asarray(value, dtype=np.float64))
    raise TypeError(f"{type(value).__name__} is not a scalar attribute value")


def parameters_of(meta: Mapping[str, Any]) -> Any:
    """``meta["parameters"]`` decoded when it is JSON text; a string that is not JSON as it is,
    None when absent."""
    value = meta.get("parameters")
    if isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return value
    return value


def identity_parameters(meta: Mapping[str, Any]) -> Any:
    """The resolved parameters as the fingerprint sees them: :func:`parameters_of` without
    :data:`PATH_PARAMETERS`; None when absent.

    A string that is not JSON is returned as it is (it still identifies the tree)."""
    value = parameters_of(meta)
    if isinstance(value, dict):
        value = {k: v for k, v in value.items() if k not in PATH_PARAMETERS}
    return value


def identity_sha256(meta: Mapping[str, Any], key: str) -> str:
    """The checksum one identity key contributes: :func:`value_sha256` of its value (of the
    canonical JSON of :func:`identity_parameters` for ``parameters``), or ``"absent"``."""
    if key == "parameters":
        params = identity_parameters(meta)
        if params is None:
            return ABSENT
        if not isinstance(params, str):
            params = json.dumps(params, sort_keys=True, separators=(",", ":"))
        return value_sha256(params)
    if key not in meta:
        return ABSENT
    try:
        return value_sha256(meta[key])
    except (TypeError, OverflowError):
        return value_sha256(json.dumps(meta[key], sort_keys=True, separators=(",", ":")))


def array_checksums(tree: ActionTree) -> dict[str, str]:
    """:func:`array_sha256` of every array of ``tree`` by name."""
    return {name: array_sha256(a) for name, a in tree.arrays().items()}


def tree_fingerprint(tree: ActionTree) -> str:
    """The identity of ``tree``: its datasets and its identity attributes (:data:`IDENTITY_KEYS`
    of ``tree.meta``), 64 hex digits (see :func:`fingerprint_of`)."""
    return fingerprint_of(array_checksums(tree), tree.meta)


def fingerprint_of(checksums: Mapping[str, str], meta: Mapping[str, Any]) -> str:
    """sha256 over the lines ``"<array name> <array_sha256>\\n"`` in ``LAYOUT`` order, then
    ``"@<key> <identity_sha256>\\n"`` for every key of :data:`IDENTITY_KEYS` in order.

    Args:
        checksums: :func:`array_sha256` of every ActionTree array by name.
        meta: the tree's meta (``ActionTree.meta``, as written or as read back).
    """
    h = hashlib.sha256()
    for name, _, _ in LAYOUT:
        h.update(f"{name} {checksums[name]}\n".encode("ascii"))
    for key in IDENTITY_KEYS:
        h.update(f"@{key} {identity_sha256(meta, key)}\n".encode("ascii"))
    return h.hexdigest()


def identity_changes(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[str]:
    """The identity keys whose contribution to the fingerprint differs between two metas."""
    return [k for k in IDENTITY_KEYS if identity_sha256(a, k) != identity_sha256(b, k)]
