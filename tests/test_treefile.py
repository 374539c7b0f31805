"""Tree files v3: exact round trip, atomic writes, and a clear refusal for every kind of damage
(every byte's checksum: tests/test_tree_checksums.py)."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.treegen import random_tree, resign
from thinkfast.errors import TreeFileError
from thinkfast.tree.action_tree import ActionTree
from thinkfast.tree.file import load_meta, load_tree, save_tree, tree_from_bytes
from thinkfast.tree.identity import tree_fingerprint
from thinkfast.tree.layout import DERIVED, LAYOUT, PATHS, array_sha256

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "data" / "tree_v3_golden.h5"
GOLDEN_V2 = ROOT / "tests" / "data" / "tree_v2_golden.h5"
GOLDEN_V1 = ROOT / "tests" / "data" / "tree_v1_golden.h5"


@pytest.fixture
def tree_file(tmp_path) -> Path:
    path = tmp_path / "tree.h5"
    save_tree(random_tree(1), path)
    return path


def assert_refused(path: Path, *needles: str) -> str:
    """Loading fails with one TreeFileError line that starts with the path and names every needle.

    The h5py/OS exception behind it is suppressed, so the CLI never shows a traceback chain.
    """
    with pytest.raises(TreeFileError) as info:
        load_tree(path)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    assert "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)
    err = info.value
    assert err.__cause__ is None and (err.__context__ is None or err.__suppress_context__)
    return message


def assert_same_tree(a: ActionTree, b: ActionTree) -> None:
    for name, x in a.arrays().items():
        y = getattr(b, name)
        assert y.dtype == x.dtype and y.shape == x.shape, name
        assert np.array_equal(x, y), name
    assert a.meta == b.meta


@pytest.mark.parametrize("seed, depth", [(0, 1), (1, 2), (2, 3), (3, 4)])
def test_round_trip_gives_identical_arrays_dtypes_and_meta(tmp_path, seed, depth):
    tree = random_tree(seed, max_depth=depth)
    save_tree(tree, tmp_path / "t.h5")
    back = load_tree(tmp_path / "t.h5")
    assert_same_tree(tree, back)
    assert tree_fingerprint(back) == tree_fingerprint(tree)
    assert all(not a.flags.writeable for a in back.arrays().values())


def test_a_tree_read_from_its_bytes_is_the_tree_read_from_its_file(tree_file):
    data = tree_file.read_bytes()
    assert_same_tree(load_tree(tree_file), tree_from_bytes(data))
    for bad, needle in ((b"", "not an HDF5 file"), (data[: len(data) // 2], "tree X: ")):
        with pytest.raises(TreeFileError) as info:
            tree_from_bytes(bad, "tree X")
        assert str(info.value).startswith("tree X: ") and needle in str(info.value)
    flipped = bytearray(data)  # a dataset's byte changed: the checksum refuses it
    flipped[-200] ^= 0xFF
    with pytest.raises(TreeFileError):
        tree_from_bytes(bytes(flipped), "tree X")


def test_tree_without_terminals_round_trips(tmp_path):
    tree = random_tree(5, terminals_per_leaf=0)
    assert tree.n_terminals == 0
    save_tree(tree, tmp_path / "t.h5")
    assert_same_tree(tree, load_tree(tmp_path / "t.h5"))


def test_meta_scalars_stay_native_and_the_rest_is_json_under_a_dotjson_name(tmp_path):
    meta = {"n": 3, "x": 0.5, "ok": False, "s": "é", "d": {"a": [1, 2.5, None]}, "l": [1, "b"]}
    meta["none"] = None
    meta["np"] = np.int64(7)
    meta["shield_dt"] = 0.02  # the one key v2 requires
    tree = dataclasses.replace(random_tree(0), meta=meta)
    save_tree(tree, tmp_path / "t.h5")
    with h5py.File(tmp_path / "t.h5") as f:
        assert f.attrs["d.json"] == '{"a": [1, 2.5, null]}'
        assert f.attrs["none.json"] == "null"
        assert f.attrs["n"] == 3 and "d" not in f.attrs
    back = load_tree(tmp_path / "t.h5").meta
    assert back.pop("created").endswith("Z")
    assert back == {**meta, "np": 7}
    assert type(back["n"]) is int and type(back["ok"]) is bool and type(back["np"]) is int


def test_created_is_taken_from_meta_or_is_now_in_iso_utc(tmp_path):
    tree = random_tree(0)
    save_tree(tree, tmp_path / "a.h5")
    assert load_meta(tmp_path / "a.h5")["created"] == "2025-01-01T00:00:00Z"
    meta = {k: v for k, v in tree.meta.items() if k != "created"}
    save_tree(dataclasses.replace(tree, meta=meta), tmp_path / "b.h5")
    created = load_meta(tmp_path / "b.h5")["created"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", created), created


@pytest.mark.parametrize(
    "key", ["format", "schema_version", "fingerprint", "checksums", "stats.json", ""]
)
def test_reserved_meta_keys_are_refused_on_write(tmp_path, key):
    tree = dataclasses.replace(random_tree(0), meta={key: 1})
    with pytest.raises(TreeFileError, match=re.escape(str(tmp_path / "t.h5"))):
        save_tree(tree, tmp_path / "t.h5")
    assert not (tmp_path / "t.h5").exists()


def test_meta_that_is_not_json_able_is_refused_on_write(tmp_path):
    tree = dataclasses.replace(random_tree(0), meta={"obj": object()})
    with pytest.raises(TreeFileError, match="meta\\['obj'\\] is not JSON-able"):
        save_tree(tree, tmp_path / "t.h5")


def test_an_invalid_tree_is_refused_on_write(tmp_path):
    tree = random_tree(0)
    parent = tree.node_parent.copy()
    parent[3] = 5
    with pytest.raises(TreeFileError, match="refusing to write an invalid tree: /nodes/parent"):
        save_tree(dataclasses.replace(tree, node_parent=parent), tmp_path / "t.h5")
    wrong_dtype = dataclasses.replace(tree, node_ttc=tree.node_ttc.astype(np.float32))
    with pytest.raises(TreeFileError, match="/nodes/ttc has dtype float32, expected float64"):
        save_tree(wrong_dtype, tmp_path / "t.h5")


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, tree_file, monkeypatch):
    before = tree_file.read_bytes()

    def broken(f, *args):
        f.create_dataset("/partial", data=np.zeros(3))
        raise OSError("disk full")

    monkeypatch.setattr("thinkfast.tree.file._write", broken)
    with pytest.raises(TreeFileError, match="cannot write \\(disk full\\)"):
        save_tree(random_tree(2), tree_file)
    assert tree_file.read_bytes() == before
    assert sorted(p.name for p in tree_file.parent.iterdir()) == [tree_file.name]


def test_writing_into_a_missing_directory_names_it(tmp_path):
    with pytest.raises(TreeFileError, match="directory .*nope does not exist"):
        save_tree(random_tree(0), tmp_path / "nope" / "t.h5")


def test_golden_v1_file_is_refused_naming_its_version_and_the_fix():
    """v1 files have no shield paths: refused in one line that says what to do."""
    message = assert_refused(
        GOLDEN_V1, "schema_version 1 is not supported (this thinkfast reads 3)", "no shield paths"
    )
    assert "recompile it with `thinkfast-compile tree CONFIG.toml -o tree_v1_golden.h5`" in message
    with pytest.raises(TreeFileError, match="schema_version 1 is not supported"):
        load_meta(GOLDEN_V1)


def test_golden_v2_file_is_refused_naming_its_version_and_the_fix():
    """v2 files have no checksums of their attributes (the runtime's settings) and a fingerprint
    of the datasets alone: refused by every reader, in one line that says to recompile."""
    message = assert_refused(
        GOLDEN_V2,
        "schema_version 2 is not supported (this thinkfast reads 3)",
        "v2 has no checksums of its attributes",
        "recompile it with `thinkfast-compile tree CONFIG.toml -o tree_v2_golden.h5`",
    )
    with pytest.raises(TreeFileError) as info:
        load_meta(GOLDEN_V2)
    assert str(info.value) == message


def test_golden_v3_file_still_reads_with_its_known_values():
    """Breaks when a change makes this thinkfast unable to read files written as v3."""
    tree = load_tree(GOLDEN)
    assert GOLDEN.stat().st_size < 50_000
    assert tree.node_parent.tolist() == [-1, 0, 0, 1, 2]
    assert tree.node_depth.tolist() == [0, 1, 1, 2, 2]
    assert tree.child_start.tolist() == [1, 3, 4, 5, 5]
    assert tree.term_count.tolist() == [0, 0, 0, 2, 2]
    assert tree.edge_kind.tolist() == [1, 0, 0, 0, 1]
    assert tree.term_goal.tolist() == [0, 1, 1, 2]
    assert np.allclose(tree.node_ttc, [0.0, 0.1, 0.1, 0.2, 0.2], rtol=0, atol=1e-15)
    assert np.allclose(tree.term_arrival, [0.5, 0.45, 0.4, 0.55], rtol=0, atol=1e-15)
    assert tree.node_state[4, 8] == 0.44 and tree.node_q[1, 0] == -0.4
    assert tree.goal_yz.tolist() == [[-0.15, 0.85], [0.0, 1.0], [0.15, 0.85]]
    assert tree.grid_reachable.tolist() == [True, True, False, True]
    assert tree.subgoal_goal.tolist() == [0, 2]
    assert tree.meta["discards"] == {"position_limit": 2, "collision": 1}
    assert tree.meta["deterministic"] is True and tree.meta["jobs"] == 1
    assert tree.meta["created"] == "2025-01-01T00:00:00Z"
    assert "max_depth = 2" in tree.meta["config_text"]
    assert tree.meta["config_sha256"].startswith("0bc819342769")
    assert json.loads(tree.meta["parameters"])["tree"]["max_depth"] == 2
    assert tree.meta["robot_name"] == "golden" and tree.meta["machine"]["cpu"] == "Golden CPU"
    assert tree.meta["shield_dt"] == 0.05
    assert tree.edge_shield.shape == (5, 3, 3) and tree.term_shield.shape == (4, 8, 3)
    assert np.allclose(tree.edge_shield[3, 2], [0.7, 0.3, 1.0], rtol=0, atol=1e-15)
    assert np.allclose(tree.term_shield[1, 2], [0.74, 0.0, 1.0], rtol=0, atol=1e-15)
    assert np.allclose(tree.term_shield[2, 7], [0.8, 0.0, 1.0], rtol=0, atol=1e-15)  # held
    assert tree_fingerprint(tree) == (
        "7e354edd593e18e97bc41d31fea5953e83ecb686ee18facfcaf89a8365390303"
    )


def test_every_tree_array_has_a_dataset_and_every_dataset_is_documented():
    names = {f.name for f in dataclasses.fields(ActionTree)} - {"meta"}
    assert set(PATHS) == names and len(LAYOUT) == len(names)
    doc = (ROOT / "docs" / "TREE_FORMAT.md").read_text()
    for path in [*PATHS.values(), *(p for p, _, _ in DERIVED)]:
        assert f"`{path}`" in doc, path


def test_every_dataset_carries_units_doc_and_checksum(tree_file):
    with h5py.File(tree_file) as f:
        assert f.attrs["format"] == "thinkfast-tree" and f.attrs["schema_version"] == 3
        for path in [*PATHS.values(), *(p for p, _, _ in DERIVED)]:
            ds = f[path]
            assert ds.attrs["units"] and ds.attrs["doc"]
            assert ds.attrs["sha256"] == array_sha256(ds[()])


# --- damage: every case is one clear TreeFileError naming the path and the reason ---


def test_missing_file(tmp_path):
    assert_refused(tmp_path / "absent.h5", "file not found")


@pytest.mark.parametrize("content", [b"", b"not a tree\n", b"\x89PNG\r\n\x1a\n" + bytes(600)])
def test_non_hdf5_file(tmp_path, content):
    path = tmp_path / "x.h5"
    path.write_bytes(content)
    assert_refused(path, "not an HDF5 file")


def test_a_directory_is_not_readable(tmp_path):
    assert_refused(tmp_path, "cannot read file")


@pytest.mark.parametrize("fraction", [0.05, 0.5, 0.95, 0.999])
def test_truncated_file(tree_file, fraction):
    data = tree_file.read_bytes()
    tree_file.write_bytes(data[: int(len(data) * fraction)])
    assert_refused(tree_file, "truncated or unreadable HDF5 file")


@pytest.mark.parametrize(
    "path", ["/nodes/ttc", "/nodes/state", "/edges/kind", "/terminals/arrival", "/grid/reachable"]
)
def test_one_flipped_byte_inside_a_dataset_fails_its_checksum(tree_file, path):
    with h5py.File(tree_file) as f:
        ds = f[path]
        offset = ds.id.get_offset() + ds.id.get_storage_size() // 2
    data = bytearray(tree_file.read_bytes())
    data[offset] ^= 0xFF
    tree_file.write_bytes(bytes(data))
    assert_refused(tree_file, f"dataset {path}: checksum mismatch (file is corrupt)")


@pytest.mark.parametrize("version", [7, 4, 2, 1, 0])
def test_unknown_schema_version_is_refused(tree_file, version):
    with h5py.File(tree_file, "r+") as f:
        f.attrs["schema_version"] = version
    assert_refused(tree_file, f"schema_version {version} is not supported (this thinkfast reads 3)")
    with pytest.raises(TreeFileError, match="is not supported"):
        load_meta(tree_file)


def test_schema_version_that_is_not_an_integer(tree_file):
    with h5py.File(tree_file, "r+") as f:
        f.attrs["schema_version"] = "1"
    assert_refused(tree_file, "schema_version '1' is not an integer")


def test_wrong_format_attribute(tree_file):
    with h5py.File(tree_file, "r+") as f:
        f.attrs["format"] = "thinkfast-record"
    assert_refused(tree_file, "format is 'thinkfast-record', expected 'thinkfast-tree'")


def test_hdf5_file_of_another_kind(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["data"] = np.zeros(3)
    assert_refused(path, "missing root attribute format")


@pytest.mark.parametrize(
    "path", ["/terminals/goal", "/nodes/parent", "/edges/child", "/grid/yz", "/terminals/shield"]
)
def test_missing_dataset(tree_file, path):
    with h5py.File(tree_file, "r+") as f:
        del f[path]
    assert_refused(tree_file, f"missing dataset {path}")


def rewrite(path: Path, dataset: str, data: np.ndarray) -> None:
    """Replace a dataset with valid checksums (its own and the table's): damage that only the
    structural checks can see."""
    with h5py.File(path, "r+") as f:
        attrs = dict(f[dataset].attrs)
        del f[dataset]
        f[dataset] = data
        f[dataset].attrs.update({**attrs, "sha256": array_sha256(data)})
    resign(path)


def test_wrong_dtype(tree_file):
    rewrite(tree_file, "/nodes/ttc", load_tree(tree_file).node_ttc.astype(np.float32))
    assert_refused(tree_file, "dataset /nodes/ttc: dtype float32, expected float64")


def test_rows_that_disagree_within_a_group(tree_file):
    rewrite(tree_file, "/terminals/arrival", load_tree(tree_file).term_arrival[:-1])
    assert_refused(tree_file, "/terminals/arrival has", "rows but /terminals/node has")


def test_wrong_trailing_shape(tree_file):
    rewrite(tree_file, "/nodes/state", load_tree(tree_file).node_state[:, :8].copy())
    assert_refused(tree_file, "/nodes/state has shape", "expected (N, 9)")


@pytest.mark.parametrize(
    "dataset, change, needle",
    [
        ("/nodes/parent", lambda t: _set(t.node_parent, 2, 2), "/nodes/parent[2] = 2 is not in"),
        ("/nodes/depth", lambda t: _set(t.node_depth, 1, 5), "/nodes/depth decreases"),
        ("/nodes/child_count", lambda t: _set(t.child_count, 0, 99), "a range is outside"),
        ("/nodes/term_start", lambda t: _set(t.term_start, -1, -3), "a range is outside"),
        ("/terminals/node", lambda t: t.term_node[::-1].copy(), "/terminals/node is not sorted"),
        ("/terminals/goal", lambda t: _set(t.term_goal, 0, 999), "/terminals/goal holds an index"),
        ("/edges/kind", lambda t: _set(t.edge_kind, 1, 7), "/edges/kind holds a value other"),
        ("/edges/shield", lambda t: _set(t.edge_shield, 1, np.nan), "/edges/shield holds a value"),
        ("/terminals/shield", lambda t: t.term_shield[:, :, :2].copy(), "expected (T, S, 3)"),
    ],
)
def test_layout_violations_with_valid_checksums_are_refused(tree_file, dataset, change, needle):
    rewrite(tree_file, dataset, change(load_tree(tree_file)))
    assert_refused(tree_file, "invalid tree layout", needle)


def _set(a: np.ndarray, i: int, value: int) -> np.ndarray:
    b = a.copy()
    b[i] = value
    return b


def test_derived_edge_dataset_that_disagrees_is_refused(tree_file):
    rewrite(tree_file, "/edges/child", np.zeros(load_tree(tree_file).n_nodes, dtype=np.int32))
    assert_refused(tree_file, "dataset /edges/child disagrees with /nodes")


def test_fingerprint_attribute_must_match(tree_file):
    with h5py.File(tree_file, "r+") as f:
        f.attrs["fingerprint"] = "0" * 64
    assert_refused(tree_file, "attribute fingerprint: checksum mismatch (file is corrupt)")
    resign(tree_file)
    assert_refused(
        tree_file, "attribute fingerprint does not match the datasets and identity attributes"
    )


def test_bad_json_attribute(tree_file):
    with h5py.File(tree_file, "r+") as f:
        f.attrs["discards.json"] = "{not json"
    resign(tree_file)
    assert_refused(tree_file, "attribute discards.json is not valid JSON")


def test_missing_checksum_attribute(tree_file):
    with h5py.File(tree_file, "r+") as f:
        del f["/goals/q"].attrs["sha256"]
    assert_refused(tree_file, "missing attribute /goals/q@sha256")


def test_shield_paths_round_trip_with_their_spacing(tmp_path):
    tree = random_tree(4)
    assert tree.term_shield.shape[1] > 1 and tree.edge_shield.shape[1] == 6
    save_tree(tree, tmp_path / "t.h5")
    back = load_tree(tmp_path / "t.h5")
    assert np.array_equal(back.edge_shield, tree.edge_shield)
    assert np.array_equal(back.term_shield, tree.term_shield)
    assert back.meta["shield_dt"] == 0.02


@pytest.mark.parametrize("value", [None, 0.0, -0.02, "0.02"])
def test_a_missing_or_bad_shield_spacing_is_refused(tmp_path, tree_file, value):
    with h5py.File(tree_file, "r+") as f:
        if value is None:
            del f.attrs["shield_dt"]
        else:
            f.attrs["shield_dt"] = value
    assert_refused(tree_file, "attribute shield_dt")  # the checksum table first
    resign(tree_file)
    assert_refused(tree_file, "meta shield_dt (sample spacing of the shield paths, s)")
    meta = {k: v for k, v in random_tree(0).meta.items() if k != "shield_dt"}
    with pytest.raises(TreeFileError, match="shield_dt"):
        save_tree(dataclasses.replace(random_tree(0), meta=meta), tmp_path / "x.h5")


def test_one_field_table_describes_every_array_and_the_document_agrees():
    """FIELDS is the one source: the ActionTree's arrays, the writer's layout and units, and the
    dataset table of docs/TREE_FORMAT.md all follow it."""
    import dataclasses
    import re
    from pathlib import Path

    from thinkfast.tree.action_tree import DTYPES, FIELDS, UNITS, ActionTree
    from thinkfast.tree.layout import LAYOUT

    names = [f.name for f in dataclasses.fields(ActionTree) if f.name != "meta"]
    assert sorted(f.name for f in FIELDS) == sorted(names)
    assert [(f.name, f.path, f.doc) for f in FIELDS] == list(LAYOUT)
    assert set(DTYPES) == set(UNITS) == set(names)
    doc = (Path(__file__).resolve().parents[1] / "docs" / "TREE_FORMAT.md").read_text()
    row = r"^\| `(/\w+/\w+)` \| `(\w+)` \| (\w+)[^|]* \| \(([^)]*)\) \| ([^|]+) \|"
    rows = {m[0]: m[1:] for m in re.findall(row, doc, re.M)}
    for f in FIELDS:
        assert f.path in rows, f"{f.path} missing from docs/TREE_FORMAT.md"
        name, dtype, shape, unit = rows[f.path]
        assert name == f.name and dtype == np.dtype(f.dtype).name, f.path
        assert shape.split(",")[0] == f.rows, f.path
        assert f.unit.startswith(unit.strip()), (f.path, unit, f.unit)


def test_provenance_is_typed_and_refuses_what_is_missing(small_tree_015):
    from thinkfast.errors import TreeFileError
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.provenance import Provenance

    t = load_tree(small_tree_015)
    prov = Provenance.of(t.meta)
    assert prov.plane_x == 0.8 and prov.eps > 0.0 and prov.shield_dt > 0.0
    assert prov.versions["thinkfast"] and prov.versions["ruckig"]
    assert len(prov.config_sha256) == 64 and prov.parameters["tree"]["eps"] == prov.eps
    robot = prov.robot_toml()
    assert robot is None or robot.is_file()
    broken = {k: v for k, v in t.meta.items() if k != "config_sha256"}
    with pytest.raises(TreeFileError, match="config_sha256"):
        Provenance.of(broken, "x.h5")
    with pytest.raises(TreeFileError, match="parameters"):
        Provenance.of({**t.meta, "parameters": "[1, 2]"}, "x.h5")
