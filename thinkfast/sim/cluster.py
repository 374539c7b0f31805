"""Sweeps and benches as tasks: in this process, on an embedded Dask cluster, or on a running one.

Tasks (plain functions, so a Dask worker needs only this package and the robot files):

* :func:`compile_task`: compile one tree from a config text; returns the HDF5 file's bytes.
* :func:`given_task`: a tree that is already compiled (its bytes ride in the task itself, so a
  lost copy is recomputed by the scheduler like any other result).
* :func:`chunk_task`: a range of throws of one point, every planner; the tree is a task result.

Each throw's camera noise is seeded by its index (:func:`thinkfast.sim.bench.throw_seed`) and a
worker builds its lockstep world once per (tree, runtime config), exactly as a ``bench``
process does: results are identical for any number of workers or chunk size.

The client (:func:`run_sweep`) writes every finished chunk and point to the results directory
as it arrives (:class:`~thinkfast.sim.sweep_store.SweepStore`); when a worker dies, Dask runs its
unfinished tasks elsewhere, and a rerun after any interruption recomputes only what is missing.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import sys
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
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


# --- sweep ----------------------------------------------------------------------------------


@dataclass
class SweepReport:
    """What a sweep run did: points from disk / computed, chunks and trees computed, failures."""

    points: int = 0
    points_from_disk: int = 0
    chunks_from_disk: int = 0
    chunks_computed: int = 0
    trees_compiled: int = 0
    trees_from_disk: int = 0
    failures: list[str] = field(default_factory=list)
    docs: list[dict] = field(default_factory=list)
    seconds: float = 0.0


class SweepProgress:
    """One status line on stderr: trees, chunks, points, elapsed; a line per finished point
    when stderr is not a terminal."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.start = time.perf_counter()

    def __call__(self, state: dict[str, Any], event: str | None = None) -> None:
        line = (
            f"sweep: trees {state['trees_done']}/{state['trees']}, chunks "
            f"{state['chunks_done']}/{state['chunks']}, points {state['points_done']}/"
            f"{state['points']} ({time.perf_counter() - self.start:.0f} s)"
        )
        if self.tty:
            print(f"\r{line}" + (f"  {event}" if event else ""), end="", file=self.stream,
                  flush=True)  # fmt: skip
            if state["points_done"] == state["points"]:
                print(file=self.stream)
        elif event:
            print(f"{line}: {event}", file=self.stream, flush=True)


def run_sweep(sweep, store, client, progress: Callable | None = None) -> SweepReport:
    """Run every point of ``sweep`` not yet in ``store``; write chunks and points as they
    finish; returns the report (``docs``: every finished point, in sweep order).

    A compile that fails fails its points (named in ``report.failures``); the others go on.
    """
    from thinkfast.sim.sweep import compile_text
    from thinkfast.sim.sweep_store import point_doc

    t0 = time.perf_counter()
    rep = SweepReport(points=len(sweep.points))
    chunks = sweep.chunks
    docs: dict[int, dict] = {}
    partial: dict[str, dict[tuple[int, int], tuple[list, float]]] = {}
    todo = []
    for p in sweep.points:
        doc = store.load_point(p.point_key)
        if doc is not None and doc.get("point_key") == p.point_key:
            docs[p.index] = doc
            rep.points_from_disk += 1
            continue
        have = {}
        for c in chunks:
            got = store.load_chunk(p.point_key, *c)
            if got is not None:
                have[c] = got
        rep.chunks_from_disk += len(have)
        partial[p.point_key] = have
        todo.append(p)

    def finish(p) -> None:
        have = partial.pop(p.point_key)
        outcomes = [o for c in chunks for o in have[c][0]]
        doc = point_doc(sweep, p, outcomes, sum(have[c][1] for c in chunks))
        store.save_point(doc)
        docs[p.index] = doc

    trees: dict[str, Any] = {}  # tree key -> its future (kept: chunks depend on it)
    jobs: dict[str, tuple] = {}  # future key -> what it is
    futures: list = []  # to wait for: compiles and chunks, in submission order
    robot = str(sweep.robot_path)
    for p in todo:
        missing = [c for c in chunks if c not in partial[p.point_key]]
        if not missing:
            finish(p)
            continue
        if p.tree_key not in trees:
            tp = store.tree_path(p.tree_key)
            if tp.is_file():
                fut = client.submit(given_task, tp.read_bytes(), key=f"tree-{p.tree_key[:16]}")
                rep.trees_from_disk += 1
            else:
                text = compile_text(p.compile_config, sweep.robot_path)
                fut = client.submit(compile_task, text, robot, sweep.robot_hashes,
                                    key=f"compile-{p.tree_key[:16]}", priority=100)  # fmt: skip
                jobs[fut.key] = ("tree", p.tree_key, text)
                futures.append(fut)
            trees[p.tree_key] = fut
        for c in missing:
            fut = client.submit(
                chunk_task, trees[p.tree_key], p.run_config, robot, sweep.robot_hashes,
                sweep.throws[c[0]:c[1]], list(sweep.settings.planners), sweep.settings.seed,
                c[0], key=f"chunk-{p.point_key[:16]}-{c[0]}-{c[1]}", priority=-p.index,
            )  # fmt: skip
            jobs[fut.key] = ("chunk", p, c)
            futures.append(fut)
    state = {
        "trees": sum(1 for j in jobs.values() if j[0] == "tree"), "trees_done": 0,
        "chunks": sum(1 for j in jobs.values() if j[0] == "chunk"), "chunks_done": 0,
        "points": len(sweep.points), "points_done": len(docs),
    }  # fmt: skip
    failed: set[str] = set()
    if progress:
        progress(state, f"{len(docs)} points from disk" if docs else None)
    for fut in client.as_completed(futures):
        kind, *info = jobs[fut.key]
        if fut.status != "finished":  # error, or cancelled
            exc = fut.exception() if fut.status == "error" else None
            tree = info[0].tree_key if kind == "chunk" else info[0]
            name = info[0].point_key if kind == "chunk" else tree
            if tree not in failed and name not in failed:  # once per tree, else once per point
                failed.add(name)
                rep.failures.append(_failure(kind, info, exc))
            continue
        if kind == "tree":
            key, text = info
            store.save_tree(key, fut.result(), text)
            rep.trees_compiled += 1
            state["trees_done"] += 1
            event = f"tree {key[:12]} compiled"
        else:
            p, c = info
            outcomes, seconds = fut.result()
            store.save_chunk(p.point_key, *c, outcomes, seconds)
            partial[p.point_key][c] = (outcomes, seconds)
            rep.chunks_computed += 1
            state["chunks_done"] += 1
            fut.release()
            event = None
            if len(partial[p.point_key]) == len(chunks):
                finish(p)
                state["points_done"] += 1
                event = f"point {p.index} done"
        if progress:
            progress(state, event)
    rep.docs = [docs[i] for i in sorted(docs)]
    rep.seconds = time.perf_counter() - t0
    return rep


def _failure(kind: str, info, exc: BaseException | None) -> str:
    msg = str(exc).strip().splitlines()[0] if exc is not None and str(exc).strip() else repr(exc)
    if kind == "tree":
        return f"tree {info[0][:12]}: {msg}"
    p = info[0]
    vals = ", ".join(f"{k} = {v}" for k, v in p.params.items()) or "base"
    return f"point {p.index} ({vals}): {msg}"


# --- one bench ------------------------------------------------------------------------------


def bench_on_client(
    client, tree_path: Path, run_cfg, throws, planners, seed: int, chunk: int,
    progress: Callable[[int, int], None] | None = None,
) -> list:  # fmt: skip
    """The rows :func:`thinkfast.sim.bench.run_bench` gives, computed as chunks of ``chunk``
    throws on ``client`` (the default robot, which every worker must have the same)."""
    from thinkfast.robot.model import load_robot

    robot = load_robot()
    hashes = (robot.urdf_sha256, robot.toml_sha256)
    data = Path(tree_path).read_bytes()
    digest = hashlib.sha256(data).hexdigest()[:16]
    tree = client.submit(given_task, data, key=f"tree-{digest}")
    futures, where = [], {}
    run = uuid.uuid4().hex[:12]  # this bench's tasks (another client's may differ in anything)
    for s in range(0, len(throws), chunk):
        fut = client.submit(
            chunk_task, tree, run_cfg, None, hashes, throws[s:s + chunk], list(planners), seed,
            s, key=f"bench-{run}-{s}",
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
