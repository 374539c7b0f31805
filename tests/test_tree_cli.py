"""thinkfast-compile tree / info / diff / verify as real processes on real HDF5 files."""

from __future__ import annotations

import re
import shutil

import h5py
import pytest

from tests.conftest import ROBOT_TOML, assert_one_line_error, compile_cached, run_cli

BASE = """
robot = "{robot}"
[goals]
spacing = 0.45
[tree]
max_depth = {depth}
eps = {eps}
subgoal_spacing = 0.9
connect_radius = 0.25
"""


def _config(tmp_path, name, depth=2, eps=0.1):
    path = tmp_path / f"{name}.toml"
    path.write_text(BASE.format(robot=ROBOT_TOML, depth=depth, eps=eps))
    return path


@pytest.fixture(scope="module")
def trees(tmp_path_factory):
    """Tree ``a`` compiled by ``thinkfast-compile tree``; the two it is compared with (one
    parameter changed each) by the same compiler in this process, through the tests' cache."""
    tmp = tmp_path_factory.mktemp("cli")
    proc = run_cli(
        "thinkfast-compile", "tree", str(_config(tmp, "a")), "-o", str(tmp / "a.h5"), "--jobs", "2"
    )
    assert proc.returncode == 0, proc.stderr
    out = {"a": tmp / "a.h5"}
    for name, depth, eps in (("deeper", 3, 0.1), ("slower", 2, 0.12)):
        out[name] = compile_cached(_config(tmp, name, depth, eps), tmp / f"{name}.h5")
    out["tmp"], out["a_cfg"] = tmp, tmp / "a.toml"
    return out


def test_tree_writes_a_file_and_reports_progress_and_counts(trees):
    proc = run_cli("thinkfast-compile", "info", str(trees["a"]))
    assert proc.returncode == 0
    assert (
        "depth" in proc.stdout
        and "terminals" in proc.stdout
        and "tree.max_depth = 2" in proc.stdout
    )
    for shown in ("machine:\n  cpu = ", "  blas.architecture = ", "  numpy_simd.found = "):
        assert shown in proc.stdout, shown
    for version in ("h5py", "scipy", "trimesh", "fcl", "numpy", "ruckig", "pinocchio"):
        assert f"  {version}_version = " in proc.stdout, version


def test_if_changed_skips_an_up_to_date_tree(trees):
    proc = run_cli(
        "thinkfast-compile", "tree", str(trees["a_cfg"]), "-o", str(trees["a"]), "--if-changed"
    )
    assert proc.returncode == 0 and "up to date" in proc.stdout


def test_if_changed_does_not_trust_a_tree_whose_parameters_were_edited(trees, capsys):
    """--if-changed reads the file like every reader: one byte changed in its ``parameters``
    and it is compiled again (said on stderr), not kept."""
    from thinkfast.compile.cli import _up_to_date
    from thinkfast.compile.config import load_compile_config

    loaded = load_compile_config(trees["a_cfg"])
    assert _up_to_date(trees["a"], loaded)
    bad = trees["tmp"] / "if_changed.h5"
    _corrupt(trees["a"], bad, "parameters")
    assert not _up_to_date(bad, loaded)
    assert "compiling again: " in capsys.readouterr().err


def test_diff_of_a_tree_with_itself_exits_0(trees):
    proc = run_cli("thinkfast-compile", "diff", str(trees["a"]), str(trees["a"]))
    assert proc.returncode == 0, proc.stdout


def test_info_and_diff_print_one_fingerprint_the_files_and_the_daemons(trees):
    """The start log's ``tree_fingerprint`` (the daemon's :func:`tree_fingerprint`) is the one
    ``info`` and ``diff`` print, and the file's stored attribute."""
    from thinkfast.tree.file import load_tree, tree_fingerprint

    info = run_cli("thinkfast-compile", "info", str(trees["a"]))
    diff = run_cli("thinkfast-compile", "diff", str(trees["a"]), str(trees["deeper"]))
    shown = [re.findall(r"fingerprint ([0-9a-f]{16})\b", p.stdout) for p in (info, diff)]
    with h5py.File(trees["a"], "r") as f:
        stored = f.attrs["fingerprint"]
    stored = stored.decode() if isinstance(stored, bytes) else str(stored)
    daemon = tree_fingerprint(load_tree(trees["a"]))
    assert stored == daemon
    assert shown[0] == [daemon[:16]], info.stdout
    assert shown[1][0] == daemon[:16] and shown[1][1] != daemon[:16], diff.stdout


@pytest.mark.parametrize("other, key", [("deeper", "tree.max_depth"), ("slower", "tree.eps")])
def test_diff_reports_a_changed_parameter_and_exits_1(trees, other, key):
    png = trees["tmp"] / f"diff_{other}.png"
    proc = run_cli(
        "thinkfast-compile", "diff", str(trees["a"]), str(trees[other]), "--png", str(png)
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[2:4] == [
        "provenance:",
        "  parameters: 1 of 23 differ (resolved, defaults filled in):",
    ]
    assert lines[4].startswith(f"    {key}: ")
    for same in ("  robot files: equal", "  versions: equal", "  machine: equal"):
        assert any(line.startswith(same) for line in lines), same
    assert not any(line.startswith("defect") for line in lines)
    assert lines[-1] == f"wrote {png}" and lines[-2] == "different: datasets and parameters differ"
    assert png.stat().st_size > 10_000


def test_verify_passes_on_a_compiled_tree(trees):
    proc = run_cli("thinkfast-compile", "verify", str(trees["a"]), "--jobs", "2")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "verify: OK" in proc.stdout


def _corrupt(src, dst, how):
    shutil.copy(src, dst)
    if how == "truncated":
        data = dst.read_bytes()
        dst.write_bytes(data[: len(data) // 2])
    elif how == "flipped":
        with h5py.File(dst, "r") as f:
            ds = f["nodes/ttc"]
            offset = ds.id.get_offset() + 8 * 3
        data = bytearray(dst.read_bytes())
        data[offset] ^= 0x40
        dst.write_bytes(bytes(data))
    elif how == "version":
        with h5py.File(dst, "r+") as f:
            f.attrs["schema_version"] = 99
    elif how == "not_hdf5":
        dst.write_text("this is not a tree\n")
    elif how == "parameters":  # the user's case: the plane moved inside the runtime's settings
        data = dst.read_bytes()
        assert data.count(b'"distance": 0.8') == 1
        dst.write_bytes(data.replace(b'"distance": 0.8', b'"distance": 0.9'))
    elif how == "v2":  # written before the checksum table
        with h5py.File(dst, "r+") as f:
            f.attrs["schema_version"] = 2


@pytest.mark.parametrize(
    "how, needle, commands",
    [
        ("truncated", "HDF5", ("info",)),
        ("flipped", "checksum", ("verify",)),
        ("version", "schema_version", ("diff",)),
        ("not_hdf5", "not an HDF5 file", ("info", "verify", "diff")),
        (
            "parameters",
            "attribute parameters: checksum mismatch (file is corrupt)",
            ("info", "verify", "diff"),
        ),
        ("v2", "v2 has no checksums of its attributes", ("info", "verify", "diff")),
    ],
)
def test_damaged_files_are_refused_with_path_and_reason(trees, how, needle, commands):
    """Each damage refused by a command (the load behind the three is the same), a file that
    is not HDF5 by all three: one line naming the file and the reason."""
    bad = trees["tmp"] / f"bad_{how}.h5"
    _corrupt(trees["a"], bad, how)
    for cmd in commands:
        if cmd == "diff":
            proc = run_cli("thinkfast-compile", "diff", str(trees["a"]), str(bad))
            assert proc.returncode == 2
            assert_one_line_error(proc, needle)
        else:
            assert_one_line_error(run_cli("thinkfast-compile", cmd, str(bad)), str(bad), needle)


def test_verify_catches_edges_that_do_not_recompute(trees):
    """A tree re-saved with valid checksums but one state and one duration altered fails verify."""
    import dataclasses

    import numpy as np

    from thinkfast.tree.file import load_tree, save_tree

    t = load_tree(trees["a"])
    state = np.array(t.node_state)
    state[3, 0] += 1e-6  # a node 1 urad off its primitive's end
    duration = np.array(t.term_duration)
    duration[5] += 1e-3
    arrival = np.array(t.term_arrival)
    arrival[5] += 1e-3  # kept consistent: only the recomputation can tell
    bad = dataclasses.replace(t, node_state=state, term_duration=duration, term_arrival=arrival)
    path = trees["tmp"] / "altered.h5"
    save_tree(bad, path)
    proc = run_cli("thinkfast-compile", "verify", str(path), "--jobs", "1")
    assert proc.returncode == 1, proc.stdout
    assert "node 3: state differs" in proc.stdout
    assert "terminal 5: duration" in proc.stdout


def test_verify_catches_tampered_shield_paths_and_info_shows_them(trees):
    """Shield samples moved by 1 mm (checksums valid) fail verify, named by edge."""
    import dataclasses

    import numpy as np

    from thinkfast.tree.file import load_tree, save_tree

    t = load_tree(trees["a"])
    assert t.edge_shield.shape[1] == 6 and t.meta["shield_dt"] == pytest.approx(0.02, abs=1e-15)
    edge, term = np.array(t.edge_shield), np.array(t.term_shield)
    edge[4, 3, 1] += 1e-3
    term[7, -1, 2] -= 1e-3
    path = trees["tmp"] / "shield_tampered.h5"
    save_tree(dataclasses.replace(t, edge_shield=edge, term_shield=term), path)
    proc = run_cli("thinkfast-compile", "verify", str(path), "--jobs", "1")
    assert proc.returncode == 1, proc.stdout
    assert "edge 4: shield path differs by 0.001 m" in proc.stdout
    assert "terminal 7: shield path differs by 0.001 m" in proc.stdout
    info = run_cli("thinkfast-compile", "info", str(trees["a"]))
    assert "shield paths (every 0.02 s, coplanar normal +x): 6 samples per tree edge" in info.stdout
    diff = run_cli("thinkfast-compile", "diff", str(trees["a"]), str(path))
    assert diff.returncode == 1
    assert "tree edge paths: 1 of" in diff.stdout and "terminal paths: 1 of" in diff.stdout


def test_shield_spacing_is_the_largest_that_divides_eps():
    from thinkfast.compile.shield import sample_spacing, steps_per_edge

    assert sample_spacing(0.1, 0.02) == pytest.approx(0.02, abs=1e-15)
    assert sample_spacing(0.12, 0.05) == pytest.approx(0.04, abs=1e-15)
    assert steps_per_edge(0.12, sample_spacing(0.12, 0.05)) == 3
    with pytest.raises(ValueError, match="does not divide"):
        steps_per_edge(0.1, 0.03)
