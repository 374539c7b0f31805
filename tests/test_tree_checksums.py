"""Every byte the runtime reads is checked: the checksum table refuses any changed attribute or
dataset in every reader, naming it, and the fingerprint is the tree's identity (its datasets and
identity attributes, not when, where or how it was compiled)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.treegen import random_tree, resign
from thinkfast.cli_util import run_app
from thinkfast.compile.cli import app
from thinkfast.errors import TreeFileError
from thinkfast.tree.file import load_meta, load_tree, save_tree, tree_from_bytes
from thinkfast.tree.identity import IDENTITY_KEYS, fingerprint_of, tree_fingerprint, value_sha256
from thinkfast.tree.layout import array_sha256
from thinkfast.tree.manifest import TABLE, attr_key, canonical, label


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("pristine") / "tree.h5"
    save_tree(random_tree(1, max_depth=2), path)
    return path


@pytest.fixture
def tree_file(pristine, tmp_path) -> Path:
    path = tmp_path / "tree.h5"
    shutil.copy(pristine, path)
    return path


def file_entries(path: Path) -> dict[str, tuple[str, str | None]]:
    """Every attribute and dataset of the file: table key -> (object path, attribute name or
    None for the dataset itself)."""
    with h5py.File(path) as f:
        out = {attr_key("/", n): ("/", n) for n in f.attrs if n != TABLE}
        objects: list = []
        f.visititems(lambda _, obj: objects.append(obj))
        for obj in objects:
            out.update({attr_key(obj.name, n): (obj.name, n) for n in obj.attrs})
            if isinstance(obj, h5py.Dataset):
                out[obj.name] = (obj.name, None)
    return out


def change_one_byte(path: Path, obj: str, attr: str | None) -> None:
    """Rewrite one attribute or dataset through h5py with one byte of its value changed."""
    with h5py.File(path, "r+") as f:
        if attr is None:
            a = np.array(f[obj][()])
            raw = a.view(np.uint8).reshape(-1)
            raw[raw.size // 2] ^= 0x01
            f[obj][...] = a
            return
        v = f[obj].attrs[attr]
        if isinstance(v, str):
            b = bytearray(v.encode("utf-8"))
            b[len(b) // 2] ^= 0x01
            f[obj].attrs[attr] = b.decode("utf-8")
        else:
            a = np.array(v)
            raw = bytearray(a.tobytes())
            raw[len(raw) // 2] ^= 0x01
            f[obj].attrs[attr] = np.frombuffer(bytes(raw), dtype=a.dtype)[0]


def compile_cli(capsys, *argv: str) -> tuple[int, str]:
    """``thinkfast-compile ARGV`` in this process: (exit status, stderr)."""
    code = run_app(app, "thinkfast-compile", list(argv))
    return code, capsys.readouterr().err


def refusals(capsys, path: Path, other: Path, in_memory: bool = False) -> dict[str, str]:
    """What every reader says about ``path``: load_tree, load_meta (and tree_from_bytes when
    ``in_memory``) and the ``info``, ``verify`` and ``diff`` commands (a reader that accepts it
    says ``accepted``)."""
    out = {}
    readers = [("load_tree", lambda: load_tree(path)), ("load_meta", lambda: load_meta(path))]
    if in_memory:
        readers.append(("tree_from_bytes", lambda: tree_from_bytes(path.read_bytes(), str(path))))
    for name, read in readers:
        try:
            read()
            out[name] = "accepted"
        except TreeFileError as exc:
            out[name] = str(exc)
    for cmd, args, status in (
        ("info", [str(path)], 1),
        ("verify", [str(path), "--jobs", "1"], 1),
        ("diff", [str(path), str(other)], 2),
    ):
        code, err = compile_cli(capsys, cmd, *args)
        lines = err.strip().splitlines()
        out[cmd] = lines[0] if code == status and len(lines) == 1 else f"accepted ({code}): {err}"
    return out


def needle(key: str, attr: str | None) -> str:
    if attr in ("format", "schema_version") and key.startswith("/@"):
        return attr  # refused by the format and version checks before the table
    return f"{label(key)}: checksum mismatch (file is corrupt)"


def test_the_checksum_table_lists_every_attribute_and_dataset_and_itself(tree_file):
    with h5py.File(tree_file) as f:
        table = json.loads(f.attrs[TABLE])
        assert table["entries"]["/@parameters"] == value_sha256(f.attrs["parameters"])
        assert table["entries"]["/nodes/q@units"] == value_sha256("rad")
        assert table["entries"]["/nodes@rows"] == value_sha256("N")
        assert table["entries"]["/nodes/q"] == array_sha256(f["/nodes/q"][()])
        assert table["entries"]["/@shield_dt"] == array_sha256(np.float64(0.02))
    assert set(table["entries"]) == set(file_entries(tree_file))
    assert table["sha256"] == hashlib.sha256(canonical(table["entries"]).encode()).hexdigest()


def test_one_byte_changed_in_any_attribute_or_dataset_is_refused_by_every_reader(
    pristine, tmp_path, capsys
):
    """h5py rewrites each attribute (root, group, dataset: units, doc, sha256) and each dataset
    in turn with one byte of its value changed; load_tree, load_meta and ``info``, ``verify`` and
    ``diff`` all refuse it in one line naming what changed."""
    entries = file_entries(pristine)
    assert len(entries) > 100
    bad = tmp_path / "tree.h5"
    failures = []
    for key, (obj, attr) in entries.items():
        shutil.copy(pristine, bad)
        change_one_byte(bad, obj, attr)
        for reader, message in refusals(capsys, bad, pristine).items():
            if needle(key, attr) not in message or str(bad) not in message:
                failures.append((key, reader, message))
    assert not failures, failures[:5]


def test_a_raw_byte_flip_in_an_attribute_or_dataset_is_refused_naming_it(pristine, tmp_path):
    """One byte flipped in the file itself, for every attribute value found exactly once in the
    file and every dataset. Strings and datasets lie outside HDF5's metadata: the table names
    them. A number kept in the root's attribute heap is under HDF5's own metadata checksum,
    which refuses the root attributes first (this reader cannot tell which one)."""
    data = pristine.read_bytes()
    offsets: dict[str, tuple[int, str | None]] = {}
    with h5py.File(pristine) as f:
        table = f.attrs[TABLE].encode()
        start = data.index(table)  # a dataset's sha256 is also in the table: flip the other
        outside = data[:start] + bytes(len(table)) + data[start + len(table) :]
        for key, (obj, attr) in file_entries(pristine).items():
            if attr is None:
                ds = f[obj]
                if ds.id.get_storage_size():
                    offsets[key] = (ds.id.get_offset() + ds.id.get_storage_size() // 2, None)
                continue
            v = f[obj].attrs[attr]
            raw = v.encode("utf-8") if isinstance(v, str) else np.array(v).tobytes()
            if len(raw) >= 8 and outside.count(raw) == 1:
                offsets[key] = (outside.index(raw) + len(raw) // 2, attr)
    assert sum(1 for _, a in offsets.values() if a) > 70  # sha256, docs, parameters, ...
    bad = tmp_path / "tree.h5"
    failures, by_hdf5 = [], []
    hdf5 = f"{bad}: root attributes: unreadable ("
    for key, (offset, attr) in offsets.items():
        flipped = bytearray(data)
        flipped[offset] ^= 0x01
        bad.write_bytes(bytes(flipped))
        for read in (load_tree, load_meta):
            with pytest.raises(TreeFileError) as info:
                read(bad)
            message = str(info.value)
            if message.startswith(hdf5) and "checksum" in message and key.startswith("/@"):
                by_hdf5.append(key)
            elif needle(key, attr) not in message:
                failures.append((key, read.__name__, message))
    assert not failures, failures[:5]
    assert "/@parameters" not in by_hdf5 and "/nodes/q@units" not in by_hdf5
    assert len(by_hdf5) < len(offsets) // 4, by_hdf5


def test_the_users_case_one_parameter_changed_in_the_file_is_refused(tree_file, capsys):
    """``"distance": 0.8`` edited to 0.9 inside the ``parameters`` attribute (the runtime's plane):
    refused by every reader, naming the attribute."""
    data = tree_file.read_bytes()
    assert data.count(b'"distance": 0.8') == 1
    tree_file.write_bytes(data.replace(b'"distance": 0.8', b'"distance": 0.9'))
    expected = f"{tree_file}: attribute parameters: checksum mismatch (file is corrupt)"
    found = refusals(capsys, tree_file, tree_file, in_memory=True)
    assert len(found) == 6
    for reader, message in found.items():
        assert message.endswith(expected), (reader, message)


def test_an_attribute_or_dataset_the_table_does_not_list_is_refused(tree_file):
    with h5py.File(tree_file, "r+") as f:
        f.attrs["plane_x_override"] = 0.9
    with pytest.raises(TreeFileError, match="attribute plane_x_override is not in the checksum"):
        load_meta(tree_file)
    with h5py.File(tree_file, "r+") as f:
        del f.attrs["plane_x_override"]
        f["/nodes/extra"] = np.zeros(3)
    with pytest.raises(TreeFileError, match="dataset /nodes/extra is not in the checksum table"):
        load_tree(tree_file)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda t: t.pop("sha256"), "attribute checksums.json: not a checksum table"),
        (lambda t: t["entries"].update({"/@created": "0" * 64}), "checksums.json: checksum mis"),
        (lambda t: t["entries"].pop("/@created"), "checksums.json: checksum mismatch"),
    ],
)
def test_a_damaged_or_missing_table_is_refused_naming_it(tree_file, damage, message):
    with h5py.File(tree_file, "r+") as f:
        table = json.loads(f.attrs[TABLE])
        damage(table)
        f.attrs[TABLE] = json.dumps(table)
    with pytest.raises(TreeFileError, match=message):
        load_meta(tree_file)
    with h5py.File(tree_file, "r+") as f:
        del f.attrs[TABLE]
    with pytest.raises(TreeFileError, match="missing root attribute checksums.json"):
        load_tree(tree_file)


# --- the fingerprint: identity, not provenance ---


def test_the_fingerprint_follows_every_array_and_every_identity_attribute():
    tree = random_tree(3)
    base = tree_fingerprint(tree)
    for name, a in tree.arrays().items():
        if a.size == 0:
            continue
        b = a.copy()
        b.reshape(-1)[0] = not b.reshape(-1)[0] if b.dtype == bool else b.reshape(-1)[0] + 1
        assert tree_fingerprint(dataclasses.replace(tree, **{name: b})) != base, name
    params = json.loads(tree.meta["parameters"])
    params["plane"]["distance"] = 0.9
    changed = {
        "parameters": json.dumps(params),
        "robot_name": "irb2600",
        "urdf_sha256": "f" * 64,
        "robot_toml_sha256": "e" * 64,
        "plane_distance": 0.9,
        "shield_radius": 0.25,
        "shield_dt": 0.01,
    }
    assert set(changed) == set(IDENTITY_KEYS)
    for key, value in changed.items():
        meta = {**tree.meta, key: value}
        assert tree_fingerprint(dataclasses.replace(tree, meta=meta)) != base, key
        meta.pop(key)
        assert tree_fingerprint(dataclasses.replace(tree, meta=meta)) != base, key


def test_the_fingerprint_ignores_when_where_and_how_the_tree_was_compiled():
    """Time, paths, config text (comments), jobs, timings, versions, machine, discard counts and
    the robot file's path in the parameters: the same tree on every machine, every day."""
    tree = random_tree(3)
    params = json.loads(tree.meta["parameters"])
    params["robot"] = "/elsewhere/robots/irb1600/robot.toml"
    meta = {
        **tree.meta,
        "created": "2031-06-01T12:00:00Z",
        "config_path": "/home/someone/else.toml",
        "config_text": tree.meta["config_text"] + "# a comment\n",
        "config_sha256": "0" * 64,
        "jobs": 64,
        "compile_seconds": 1234.5,
        "numpy_version": "9.9.9",
        "machine": {"cpu": "Other CPU", "blas": {"architecture": "SkylakeX"}},
        "discards": {"collision": 99},
        "parameters": json.dumps(params, indent=2, sort_keys=True),
    }
    assert tree_fingerprint(dataclasses.replace(tree, meta=meta)) == tree_fingerprint(tree)


def test_the_stored_fingerprint_is_the_trees_and_survives_the_file(tree_file):
    tree = load_tree(tree_file)
    with h5py.File(tree_file) as f:
        stored = f.attrs["fingerprint"]
    sums = {name: array_sha256(a) for name, a in tree.arrays().items()}
    assert stored == tree_fingerprint(tree) == fingerprint_of(sums, tree.meta)
    assert tree_fingerprint(random_tree(1, max_depth=2)) == stored


def test_an_identity_attribute_changed_and_signed_again_fails_the_fingerprint(tree_file):
    """Even with a checksum table written again, the runtime's settings cannot change under the
    same fingerprint."""
    with h5py.File(tree_file, "r+") as f:
        f.attrs["plane_distance"] = 0.9
    resign(tree_file)
    with pytest.raises(TreeFileError, match="attribute fingerprint does not match the datasets"):
        load_tree(tree_file)
