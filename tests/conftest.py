"""Shared fixtures: the default robot, its kinematics and collision checker (built once)."""

from __future__ import annotations

import fcntl
import functools
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = ROOT / "trees" / "irb1600_default.toml"
ROBOT_TOML = ROOT / "robots" / "irb1600" / "robot.toml"

# The numpy decision kernels here and in every daemon and simulator the tests start (they inherit
# the variable): no numba import, no kernel loading per process. The tests of the compiled
# kernels choose them in-process (the fixtures below); thinkfast/robot/kernels.py.
os.environ.setdefault("THINKFAST_KERNELS", "numpy")


# The parallel step's longest modules (setup and calls, docs/BENCHMARKS.md "The test suite"),
# collected first: with `--no-loadscope-reorder` (Makefile) xdist hands them out first and the
# many short modules fill both workers to the end, instead of a long one running alone last.
LONG_MODULES = (  # the longest under --durations=0
    "test_sim_sweep.py",
    "test_sim_lockstep.py",
    "test_tree_cli.py",
    "test_tree_checksums.py",  # its every-byte test alone takes 20-30 s
    "test_cameras.py",
    "test_safety.py",
    "test_perception_acceptance.py",
    "test_retract.py",
    "test_calib.py",
    "test_egm_control.py",
    "test_path_value.py",
    "test_cell.py",
    "test_branches.py",
    "test_record_tools.py",
)


def pytest_collection_modifyitems(items):
    """The items of :data:`LONG_MODULES` first, in that order; the rest keep theirs."""
    rank = {name: i for i, name in enumerate(LONG_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture()
def compiled_kernels():
    """The compiled decision kernels in this process for one test, then the choice before."""
    from thinkfast.robot import kernels

    before = kernels.use("compiled")
    yield
    kernels.use(before)


@pytest.fixture(params=["numpy", "compiled"])
def kernel_choice(request):
    """Each decision kernel choice in this process for one test (its name), then the one before."""
    from thinkfast.robot import kernels

    before = kernels.use(request.param)
    yield request.param
    kernels.use(before)


@pytest.fixture(scope="session")
def robot():
    from thinkfast.robot.model import load_robot

    return load_robot(ROBOT_TOML)


@pytest.fixture(scope="session")
def kin(robot):
    from thinkfast.robot.kinematics import Kinematics

    return Kinematics(robot)


@pytest.fixture(scope="session")
def small_tree_015(tmp_path_factory):
    """The small test tree with goals every 0.15 m, compiled once per session (read-only)."""
    return compile_small_tree(tmp_path_factory.mktemp("small015"), spacing=0.15)


@pytest.fixture()
def sessions():
    """Two zenoh peers on loopback, multicast scouting off: (the listening one, the one
    connected to it)."""
    from thinkfast.contract.zenoh_session import loopback_endpoint, open_peer

    ep = loopback_endpoint()
    listening = open_peer(listen=[ep])
    connected = open_peer(connect=[ep])
    yield listening, connected
    connected.close()
    listening.close()


@pytest.fixture(scope="session")
def checker(robot):
    from thinkfast.robot.collision import CollisionChecker

    return CollisionChecker(robot)


def run_cli(
    *args: str, cwd: Path | None = None, timeout: float = 600
) -> subprocess.CompletedProcess:
    """Run a console script of this package as a real process; returns the completed process."""
    exe = Path(sys.executable).parent / args[0]
    env = dict(os.environ)
    env.pop("THINKFAST_DEBUG", None)
    return subprocess.run(
        [str(exe), *args[1:]],
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        timeout=timeout,
        env=env,
    )


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    """A CLI failure: non-zero exit, one line on stderr naming every needle, no traceback."""
    assert proc.returncode != 0, proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


SMALL_TREE = """robot = "{robot}"
[goals]
spacing = {spacing}
[tree]
max_depth = {depth}
subgoal_spacing = {subgoal}
connect_radius = {radius}
"""


def small_tree_config(
    directory: Path,
    robot: Path = ROBOT_TOML,
    spacing: float = 0.3,
    depth: int = 2,
    subgoal: float = 0.6,
    radius: float = 0.3,
) -> Path:
    """Write a small compile configuration of the default family; returns its path."""
    path = directory / "small_tree.toml"
    path.write_text(
        SMALL_TREE.format(robot=robot, spacing=spacing, depth=depth, subgoal=subgoal, radius=radius)
    )
    return path


@functools.cache
def _compiler_sources_digest() -> str:
    """SHA-256 over everything a compiled tree depends on: the compiler's, robot's and tree
    file's sources and the robot description (so a cached tree is never stale). Read once per
    test process: the sources do not change while the tests run."""
    h = hashlib.sha256()
    roots = [ROOT / "thinkfast" / d for d in ("compile", "robot", "tree")]
    files = [f for r in roots for f in sorted(r.rglob("*.py"))]
    files += sorted((ROOT / "robots").rglob("*"))
    files += [ROOT / "thinkfast" / "config.py", ROOT / "thinkfast" / "errors.py"]
    for f in files:
        if f.is_file():
            h.update(str(f.relative_to(ROOT)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


TREE_CACHE = Path(tempfile.gettempdir()) / "tftest-trees"


def compile_small_tree(directory: Path, **kwargs) -> Path:
    """Compile :func:`small_tree_config` into ``directory/small_tree.h5``; returns its path
    (through :func:`compile_cached`)."""
    return compile_cached(small_tree_config(directory, **kwargs), directory / "small_tree.h5")


def compile_cached(config: Path, path: Path) -> Path:
    """Compile the tree of the compile config file ``config`` into ``path``; returns ``path``.

    The same config always gives the same tree, so each one is compiled once per machine and
    source state: test processes (parallel workers, the real-time step) share a cache keyed by
    the config text, :func:`_compiler_sources_digest` and the files of the config's robot folder,
    filled under a file lock; every caller
    gets its own copy (tests may damage theirs).
    """
    from thinkfast.compile.build import compile_tree
    from thinkfast.compile.config import load_compile_config
    from thinkfast.tree.file import save_tree

    h = hashlib.sha256((config.read_text() + _compiler_sources_digest()).encode())
    robot_dir = load_compile_config(config).robot_path.parent  # a robot folder outside robots/
    for f in sorted(robot_dir.glob("*")) if robot_dir.is_dir() else ():
        if f.is_file():
            h.update(f.name.encode() + f.read_bytes())
    key = h.hexdigest()[:24]
    TREE_CACHE.mkdir(exist_ok=True)
    cached = TREE_CACHE / f"{key}.h5"
    with open(TREE_CACHE / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not cached.exists():
            part = TREE_CACHE / f"{key}.{os.getpid()}.part"
            save_tree(compile_tree(load_compile_config(config), jobs=2), part)
            os.replace(part, cached)
    shutil.copyfile(cached, path)
    return path


def _live_daemons() -> list:
    """The real daemons started through tests/daemon_harness.py and not stopped yet."""
    runs = []
    for name in ("tests.daemon_harness", "daemon_harness"):  # imported either way by tests
        harness = sys.modules.get(name)
        runs += list(harness.DaemonRun.live) if harness is not None else []
    return runs


@pytest.fixture(autouse=True)
def _no_daemon_outlives_its_test():
    """Stop any real daemon a test started and did not stop (tests/daemon_harness.py). Daemons
    of wider-scoped fixtures (set up before this one) are theirs to stop."""
    before = {id(run) for run in _live_daemons()}
    yield
    for run in _live_daemons():
        if id(run) not in before:
            run.stop(timeout=5.0)


HOME_J6 = 0.5  # joint_6 at home [rad] of the robot of other_home_tree (the default's is 0)
TURNED_NAME = "abb_turned"  # its name


def other_home_tree(directory: Path) -> tuple[Path, Path]:
    """A robot folder made in ``directory`` (robots/irb1600 copied, its robot.toml's home with
    joint_6 = :data:`HOME_J6`: another joint vector, the same shield pose, so still on the
    plane) and a small tree compiled for it (goals every 0.3 m, max_depth 1): (tree, robot.toml)."""
    rdir = directory / "turned"
    shutil.copytree(ROBOT_TOML.parent, rdir)
    toml = rdir / "robot.toml"
    text = toml.read_text()
    assert text.count(", 0.0]\n\n# Data sheet") == 1
    text = text.replace(", 0.0]\n\n# Data sheet", f", {HOME_J6!r}]\n\n# Data sheet")
    toml.write_text(text.replace('name = "abb_irb1600_10_145"', f'name = "{TURNED_NAME}"'))
    config = small_tree_config(directory, robot=toml, spacing=0.3, depth=1)
    return compile_cached(config, directory / "turned.h5"), toml
