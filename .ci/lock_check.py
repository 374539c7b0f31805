#!/usr/bin/env python3
"""Whether requirements.lock was compiled from pyproject.toml's dependencies as they are now.

`make install` installs requirements.lock (exact versions, hashes) and then the package with
``--no-deps``, so a dependency changed in pyproject.toml alone would never reach an install.
`make lock` compiles the lock with uv and then runs this script with ``--stamp``, which writes
the lock's header: a sha256 of pyproject.toml's dependency inputs (``requires-python``,
``project.dependencies``, ``project.optional-dependencies``; each list sorted, as JSON with
sorted keys and no spaces). Without arguments the script recomputes that digest and checks
that every direct requirement (names normalised as in PEP 503) is pinned in the lock and the
project itself is not. It prints nothing when they agree, and one line and exits 1 when they
do not. Standard library only and no network: the Makefile runs it before anything is
installed (every target that installs, `make test` among them).
"""

import sys

# tomllib; the same floor as pyproject.toml's requires-python, said in one line before the import
if sys.version_info < (3, 11):  # noqa: UP036 (this runs on whatever python3 is)
    print("thinkfast needs Python >= 3.11 (python3 is older)", file=sys.stderr)
    sys.exit(2)

import argparse
import hashlib
import json
import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DIGEST_KEY = "# pyproject-sha256: "
HEADER = (
    "# requirements.lock: every package `make install` installs (all extras), one version each,\n"
    "# with its hashes, for Python >= 3.11 on any platform. Written by `make lock` (uv pip\n"
    "# compile --universal --generate-hashes: Makefile) from pyproject.toml; not to be edited\n"
    "# by hand. The digest of pyproject.toml's dependencies it was compiled from\n"
    "# (.ci/lock_check.py):\n"
)
STALE = "requirements.lock is out of date with pyproject.toml's dependencies: run `make lock`"
NAME = re.compile(r"\s*([A-Za-z0-9](?:[A-Za-z0-9._-]*[A-Za-z0-9])?)")
PIN = re.compile(r"^([A-Za-z0-9](?:[A-Za-z0-9._-]*[A-Za-z0-9])?)==", re.MULTILINE)


def normalise(name: str) -> str:
    """A distribution name as PEP 503 compares them."""
    return re.sub(r"[-_.]+", "-", name).lower()


def dependency_digest(pyproject: dict) -> str:
    """The sha256 of the dependency inputs that the lock is compiled from."""
    project = pyproject.get("project", {})
    optional = project.get("optional-dependencies", {})
    inputs = {
        "requires-python": project.get("requires-python"),
        "dependencies": sorted(project.get("dependencies", [])),
        "optional-dependencies": {extra: sorted(reqs) for extra, reqs in optional.items()},
    }
    canonical = json.dumps(inputs, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(canonical.encode()).hexdigest()


def direct_names(pyproject: dict) -> set[str]:
    """The normalised names of every direct requirement, extras included (not the project's
    own name, which an extra may name to include another)."""
    project = pyproject.get("project", {})
    reqs = list(project.get("dependencies", []))
    for extra in project.get("optional-dependencies", {}).values():
        reqs.extend(extra)
    names = {normalise(m.group(1)) for r in reqs if (m := NAME.match(r))}
    return names - {normalise(project.get("name", ""))}


def recorded_digest(lock_text: str) -> str | None:
    """The digest in the lock's header, or None without one."""
    for line in lock_text.splitlines():
        if line.startswith(DIGEST_KEY):
            return line[len(DIGEST_KEY) :].strip() or None
    return None


def problem(pyproject_path: Path, lock_path: Path) -> str | None:
    """The one line that says why the lock does not fit pyproject.toml, or None when it does."""
    if not lock_path.is_file():
        return f"{lock_path.name} is missing: run `make lock`"
    pyproject = tomllib.loads(pyproject_path.read_text())
    lock_text = lock_path.read_text()
    if recorded_digest(lock_text) != dependency_digest(pyproject):
        return STALE
    pinned = {normalise(name) for name in PIN.findall(lock_text)}
    missing = sorted(direct_names(pyproject) - pinned)
    if missing:
        return f"{STALE} (no pin for {', '.join(missing)})"
    own = normalise(pyproject.get("project", {}).get("name", ""))
    if own in pinned:
        return f"{lock_path.name} pins the project itself ({own}): run `make lock`"
    return None


def stamp(pyproject_path: Path, lock_path: Path) -> None:
    """Put the header, with the current digest, on a lock that uv has just written."""
    body = lock_path.read_text().splitlines(keepends=True)
    while body and body[0].startswith("#"):  # an older header
        body.pop(0)
    digest = dependency_digest(tomllib.loads(pyproject_path.read_text()))
    lock_path.write_text(HEADER + DIGEST_KEY + digest + "\n" + "".join(body))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pyproject", type=Path, default=ROOT / "pyproject.toml")
    parser.add_argument("--lock", type=Path, default=ROOT / "requirements.lock")
    parser.add_argument("--stamp", action="store_true", help="write the header (make lock)")
    args = parser.parse_args(argv)
    if args.stamp:
        stamp(args.pyproject, args.lock)
    line = problem(args.pyproject, args.lock)
    if line is not None:
        print(line, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
