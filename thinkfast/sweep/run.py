"""Run a sweep on a client (:mod:`thinkfast.sim.cluster`): trees first, then every point's
chunks of throws, each finished chunk and point written to the results directory as it arrives
(:class:`~thinkfast.sweep.store.SweepStore`); a rerun after any interruption recomputes only
what is missing, and a point whose tasks failed is reported, not written.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from thinkfast.sim.cluster import chunk_task, compile_task, given_task


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
    from thinkfast.sweep.spec import compile_text
    from thinkfast.sweep.store import point_doc

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
