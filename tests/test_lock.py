"""requirements.lock and pyproject.toml agree, and .ci/lock_check.py (run by the Makefile before
anything is installed) says so in one line when they do not. Offline: the script reads files."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECK = ROOT / ".ci" / "lock_check.py"
LOCK = ROOT / "requirements.lock"
STALE = "requirements.lock is out of date with pyproject.toml's dependencies: run `make lock`"


def check(*args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(CHECK), *map(str, args)], capture_output=True, text=True, timeout=60
    )


def copies(tmp_path: Path) -> tuple[Path, Path]:
    pyproject, lock = tmp_path / "pyproject.toml", tmp_path / "requirements.lock"
    shutil.copy(ROOT / "pyproject.toml", pyproject)
    shutil.copy(LOCK, lock)
    return pyproject, lock


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


def without_pin(lock_text: str, name: str) -> str:
    """The lock with one package's entry (its pin, hashes and annotations) taken out."""
    entries = re.split(r"(?m)^(?=[A-Za-z0-9])", lock_text)
    kept = [e for e in entries if not e.startswith(f"{name}==")]
    assert len(kept) == len(entries) - 1
    return "".join(kept)


def test_the_repos_lock_fits_its_pyproject():
    out = check()
    assert (out.returncode, out.stdout, out.stderr) == (0, "", "")


def test_the_lock_pins_every_package_with_hashes_and_not_the_project():
    text = LOCK.read_text()
    entries = [e for e in re.split(r"(?m)^(?=[A-Za-z0-9])", text) if not e.startswith("#")]
    names = [re.match(r"([A-Za-z0-9][A-Za-z0-9._-]*)==", e).group(1) for e in entries]
    assert {"numpy", "scipy", "pin", "ruckig", "python-fcl", "h5py", "numba"} <= set(names)
    assert "thinkfast" not in names
    assert all("\n    --hash=sha256:" in e for e in entries)
    # a name twice only for two python version ranges (a universal lock), never unconditionally
    for e in entries:
        if names.count(re.match(r"[^=]+", e).group()) > 1:
            assert " ; python_full_version " in e.split("\n", 1)[0]
    assert not re.search(r"(?m)^(-e |--index-url|--extra-index-url|--find-links)", text)


def test_a_changed_dependency_fails_in_one_line(tmp_path):
    pyproject, lock = copies(tmp_path)
    edit(pyproject, '"numpy>=1.26,<3"', '"numpy>=2.0,<3"')
    out = check("--pyproject", pyproject, "--lock", lock)
    assert out.returncode == 1
    assert (out.stdout, out.stderr.splitlines()) == ("", [STALE])


def test_a_new_extra_or_requires_python_fails_too(tmp_path):
    pyproject, lock = copies(tmp_path)
    edit(pyproject, 'requires-python = ">=3.11"', 'requires-python = ">=3.12"')
    assert check("--pyproject", pyproject, "--lock", lock).stderr.splitlines() == [STALE]
    pyproject, lock = copies(tmp_path)
    edit(
        pyproject,
        "[project.optional-dependencies]\n",
        '[project.optional-dependencies]\nx = ["ujson"]\n',
    )
    assert check("--pyproject", pyproject, "--lock", lock).stderr.splitlines() == [STALE]


def test_settings_outside_the_dependencies_need_no_new_lock(tmp_path):
    pyproject, lock = copies(tmp_path)
    edit(pyproject, "line-length = 100", "line-length = 99")
    edit(pyproject, '"numpy>=1.26,<3",\n', '"numpy>=1.26,<3",  # a comment\n')
    out = check("--pyproject", pyproject, "--lock", lock)
    assert (out.returncode, out.stderr) == (0, "")


def test_a_direct_requirement_missing_from_the_lock_fails_in_one_line(tmp_path):
    """The digest matches, but the lock (edited by hand) has lost a direct requirement's pin."""
    pyproject, lock = copies(tmp_path)
    lock.write_text(without_pin(lock.read_text(), "ruckig"))
    out = check("--pyproject", pyproject, "--lock", lock)
    assert out.returncode == 1
    assert out.stderr.splitlines() == [f"{STALE} (no pin for ruckig)"]


def test_names_compare_as_pep_503_normalises_them(tmp_path):
    pyproject, lock = copies(tmp_path)
    edit(pyproject, '"python-fcl>=0.7"', '"Python_FCL>=0.7"')
    out = check("--pyproject", pyproject, "--lock", lock, "--stamp")  # as `make lock` would
    assert (out.returncode, out.stderr) == (0, "")


def test_stamp_writes_one_header_that_the_check_then_accepts(tmp_path):
    pyproject, lock = copies(tmp_path)
    edit(pyproject, '"numpy>=1.26,<3"', '"numpy>=2.0,<3"')
    assert check("--pyproject", pyproject, "--lock", lock).returncode == 1
    body = lock.read_text().split("\n# pyproject-sha256: ", 1)[1].split("\n", 1)[1]
    lock.write_text(body)  # what uv writes with --no-header
    assert check("--pyproject", pyproject, "--lock", lock, "--stamp").returncode == 0
    assert check("--pyproject", pyproject, "--lock", lock, "--stamp").returncode == 0  # again
    text = lock.read_text()
    assert text.count("# pyproject-sha256: ") == 1
    assert text.endswith(body)
    assert check("--pyproject", pyproject, "--lock", lock).returncode == 0


def test_a_missing_lock_fails_in_one_line(tmp_path):
    pyproject, lock = copies(tmp_path)
    lock.unlink()
    out = check("--pyproject", pyproject, "--lock", lock)
    assert out.returncode == 1
    assert out.stderr.splitlines() == ["requirements.lock is missing: run `make lock`"]
