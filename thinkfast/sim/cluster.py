"""Sweeps and benches as tasks: in this process, on an embedded Dask cluster, or on a running one.

Tasks (plain functions, so a Dask worker needs only this package and the robot files):

* :func:`compile_task`: compile one tree from a config text; returns the HDF5 file's bytes.
* :func:`given_task`: a tree that is already compiled (its bytes ride in the task itself, so a
  lost copy is recomputed by the scheduler like any other result).
* :func:`chunk_task`: a range of throws of one point, every planner; the tree is a task result.

Each throw's camera noise is seeded by its index (:func:`thinkfast.sim.bench.throw_seed`) and a
worker builds its lockstep world once per (tree, runtime config), exactly as a ``bench``
process does: results are identical for any number of workers or chunk size.

A sweep is run on a client by :func:`thinkfast.sweep.run.run_sweep`; when a worker dies,
Dask runs its unfinished tasks elsewhere.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from thinkfast.errors import ThinkfastError

LOCAL, SERIAL = "local", "serial"


class TaskError(ThinkfastError):
    """A task failed on a worker (one line: what and why). Picklable, unlike ConfigError."""


class NeedsDask(ThinkfastError):
    """Dask is not installed."""


# --- tasks (run on workers) -----------------------------------------------------------------

_CACHE: dict[str, Any] = {}
WORLDS_KEPT = 3  # lockstep worlds a worker process keeps (the most recently used)
_LOCK = threading.Lock()


def _check_robot(robot_path: str | None, hashes: tuple[str, str] | None):
    """The robot at ``robot_path`` (None: the package default), refused when its files differ
    from the client's (``hashes``: URDF and robot.toml sha256)."""
    from thinkfast.robot.model import load_robot

    robot = load_robot(robot_path)
    if hashes is not None and (robot.urdf_sha256, robot.toml_sha256) != tuple(hashes):
        import socket

        raise TaskError(
            f"worker on {socket.gethostname()}: robot files at {robot_path or 'the default path'}"
            " differ from the client's (every worker needs the same robot files)"
        )
    return robot


def compile_task(config_text: str, robot_path: str, hashes: tuple[str, str]) -> bytes:
    """Compile the tree of ``config_text`` (its robot an absolute path) in this process; the
    tree file's bytes."""
    from thinkfast.compile.build import compile_tree
    from thinkfast.compile.config import load_compile_config
    from thinkfast.tree.file import save_tree

    try:
        _check_robot(robot_path, hashes)
        with tempfile.TemporaryDirectory(prefix="thinkfast-compile-") as d:
            cfg_path, out = Path(d) / "compile.toml", Path(d) / "tree.h5"
            cfg_path.write_text(config_text, encoding="utf-8")
            save_tree(compile_tree(load_compile_config(cfg_path), jobs=1), out)
            return out.read_bytes()
    except ThinkfastError as exc:
        raise TaskError(f"compile: {exc}") from None


def given_task(data: bytes) -> bytes:
    """A tree file that needs no compiling (the bytes themselves)."""
    return data


def _world(tree_bytes: bytes, run_cfg, robot_path: str | None, hashes):
    """The lockstep world of this tree and runtime config, built once per worker process."""
    from thinkfast.config import to_dict
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World
    from thinkfast.tree.file import tree_from_bytes

    digest = hashlib.sha256(tree_bytes).hexdigest()
    key = f"{digest}:{robot_path}:{hashlib.sha256(repr(to_dict(run_cfg)).encode()).hexdigest()}"
    with _LOCK:
        worlds = _CACHE.setdefault("worlds", {})
        if key in worlds:
            worlds[key] = worlds.pop(key)  # most recently used last
            return worlds[key]
    robot = _check_robot(robot_path, hashes)
    # read in memory: a worker may be killed at any moment, and a file would stay behind
    tree = tree_from_bytes(tree_bytes, f"tree {digest[:16]}")
    world = World(tree, robot, run_cfg, ServoConfig(), CameraModelConfig())
    with _LOCK:  # a few: a sweep's chunks arrive point by point
        worlds[key] = world
        while len(worlds) > WORLDS_KEPT:
            worlds.pop(next(iter(worlds)))
    return world


def chunk_task(
    tree_bytes: bytes, run_cfg, robot_path: str | None, hashes, throws, planners, seed: int,
    start: int,
) -> tuple[list, float]:  # fmt: skip
    """Throws ``start, start + 1, ...`` of a bench, every planner: (outcomes, seconds)."""
    from thinkfast.sim.bench import run_chunk

    t0 = time.perf_counter()
    try:
        world = _world(tree_bytes, run_cfg, robot_path, hashes)
    except ThinkfastError as exc:
        raise TaskError(str(exc)) from None
    out = run_chunk(world, throws, planners, seed, start)
    return out, time.perf_counter() - t0


# --- clients --------------------------------------------------------------------------------


class _InlineFuture:
    """A task run in this process when its result is first asked for."""

    def __init__(self, key: str, fn: Callable, args: tuple):
        self.key, self._fn, self._args = key, fn, args
        self._done, self._value, self._error = False, None, None

    def _run(self) -> None:
        if self._done:
            return
        try:
            args = [a.result() if isinstance(a, _InlineFuture) else a for a in self._args]
            self._value = self._fn(*args)
        except Exception as exc:  # reported like a Dask task's error
            self._error = exc
        self._done = True

    @property
    def status(self) -> str:
        self._run()
        return "error" if self._error is not None else "finished"

    def exception(self) -> BaseException | None:
        self._run()
        return self._error

    def result(self) -> Any:
        self._run()
        if self._error is not None:
            raise self._error
        return self._value

    def release(self) -> None:
        self._value = None


class InlineClient:
    """The part of a Dask client the sweep uses, run lazily in this process, in order."""

    description = "in this process"

    def submit(self, fn: Callable, *args, key: str, priority: int = 0, retries: int = 0):
        return _InlineFuture(key, fn, args)

    @staticmethod
    def as_completed(futures) -> Iterator:
        return iter(list(futures))

    def close(self) -> None:
        pass


class DaskClient:
    """A ``distributed.Client`` (embedded local cluster or a scheduler's address)."""

    def __init__(self, client, cluster=None, description: str = ""):
        self.client, self.cluster, self.description = client, cluster, description

    def submit(self, fn: Callable, *args, key: str, priority: int = 0, retries: int = 0):
        with warnings.catch_warnings():
            # a tree's bytes ride in its task on purpose (module doc): Dask's hint to scatter
            # them instead would give up recomputing a copy lost with a worker
            warnings.filterwarnings("ignore", "Sending large graph", UserWarning)
            return self.client.submit(fn, *args, key=key, priority=priority, retries=retries,
                                      pure=False)  # fmt: skip

    @staticmethod
    def as_completed(futures) -> Iterator:
        from distributed import as_completed

        return iter(as_completed(list(futures)))

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _restore_environ(before: dict[str, str]) -> None:
    """This process's environment as it was before an embedded cluster: Dask's nannies set
    thread limits for their workers (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ... = 1,
    ``MALLOC_TRIM_THRESHOLD_``) in the parent's ``os.environ`` and leave them there, where
    every process it starts afterwards (a bench, a compile) would inherit them."""
    for key in set(os.environ) - set(before):
        del os.environ[key]
    for key, value in before.items():
        if os.environ.get(key) != value:
            os.environ[key] = value


@contextlib.contextmanager
def open_client(scheduler: str, workers: int) -> Iterator[InlineClient | DaskClient]:
    """A client for ``scheduler``: ``serial`` (this process, no Dask), ``local`` (an embedded
    Dask cluster of ``workers`` processes, one thread each) or a scheduler address
    (``tcp://HOST:8786``).

    Raises:
        NeedsDask: Dask is not installed (``pip install 'thinkfast[sweep]'``).
        ThinkfastError: the scheduler does not answer.
    """
    if scheduler == SERIAL:
        yield InlineClient()
        return
    try:
        import distributed
    except ImportError:
        raise NeedsDask(
            f"--scheduler {scheduler}: Dask is not installed (pip install 'thinkfast[sweep]', "
            "or --scheduler serial)"
        ) from None
    environ = dict(os.environ)  # the embedded cluster's nannies change it: see _restore_environ
    if scheduler == LOCAL:
        cluster = distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
            silence_logs=logging.ERROR,
        )  # fmt: skip
        client = distributed.Client(cluster)
        wrapped = DaskClient(client, cluster, f"on an embedded Dask cluster of {workers} workers")
    else:
        if "://" not in scheduler:
            raise ThinkfastError(
                f"--scheduler {scheduler!r}: expected local, serial or an address such as "
                "tcp://HOST:8786"
            )
        try:
            client = distributed.Client(scheduler, timeout=10)
        except (OSError, TimeoutError) as exc:
            raise ThinkfastError(
                f"--scheduler {scheduler}: no Dask scheduler answers ({exc})"
            ) from None
        n = len(client.scheduler_info().get("workers", {}))
        wrapped = DaskClient(client, None, f"on the Dask scheduler {scheduler} ({n} workers now)")
    try:
        yield wrapped
    finally:
        wrapped.close()
        if scheduler == LOCAL:
            _restore_environ(environ)


# --- one bench ------------------------------------------------------------------------------


def bench_on_client(
    client, tree_path: Path, run_cfg, throws, planners, seed: int, chunk: int,
    progress: Callable[[int, int], None] | None = None, robot=None,
) -> list:  # fmt: skip
    """The rows :func:`thinkfast.sim.bench.run_bench` gives, computed as chunks of ``chunk``
    throws on ``client``; ``robot``: the tree's (checked, None: the default), which every
    worker must have the same (the default robot's files: each worker's own default path)."""
    from thinkfast.robot.model import load_robot

    default = load_robot()
    robot = default if robot is None else robot
    hashes = (robot.urdf_sha256, robot.toml_sha256)
    robot_path = (
        None if hashes == (default.urdf_sha256, default.toml_sha256) else str(robot.toml_path)
    )
    data = Path(tree_path).read_bytes()
    digest = hashlib.sha256(data).hexdigest()[:16]
    tree = client.submit(given_task, data, key=f"tree-{digest}")
    futures, where = [], {}
    run = uuid.uuid4().hex[:12]  # this bench's tasks (another client's may differ in anything)
    for s in range(0, len(throws), chunk):
        fut = client.submit(
            chunk_task, tree, run_cfg, robot_path, hashes, throws[s:s + chunk], list(planners),
            seed, s, key=f"bench-{run}-{s}",
        )  # fmt: skip
        futures.append(fut)
        where[fut.key] = s
    results: dict[int, list] = {}
    done = 0
    for fut in client.as_completed(futures):
        if fut.status != "finished":
            exc = fut.exception() if fut.status == "error" else None
            raise ThinkfastError(f"bench: throws from {where[fut.key]}: {exc or fut.status}")
        s = where[fut.key]
        results[s] = fut.result()[0]
        fut.release()
        done += min(chunk, len(throws) - s)
        if progress:
            progress(done, len(throws))
    return [o for s in sorted(results) for o in results[s]]
