"""Parameter sweeps on Dask: the same results as serial benches, resumable, survive a dead worker.

Real parts only: trees compiled by the compiler, Dask clusters of real processes (an embedded
local cluster, and a ``dask scheduler`` with two ``dask worker`` processes on loopback, one of
them killed with SIGKILL mid-sweep), results compared with ``thinkfast-sim bench``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tests.conftest import ROOT, assert_one_line_error, compile_cached, run_cli, small_tree_config

pytest.importorskip("distributed")

PLANNERS = ["tree", "oracle"]
THROWS, FEINTS, SEED, MIX = 1, 1, 5, "still=0.5,windup=0.5"

SWEEP = """[sweep]
compile_config = "base.toml"
planners = {planners}
throws = {throws}
feints = {feints}
seed = {seed}
mix = "{mix}"
chunk = {chunk}

[compile]
tree.eps = [0.1, 0.15]

[run]
launch.window = [6, 8]
"""


def write_sweep(directory: Path, chunk: int = 1, name: str = "sweep.toml") -> Path:
    """A sweep of 2 tiny trees x 2 launch windows (4 points) over a throw and a feint, in
    chunks of ``chunk``."""
    base = small_tree_config(directory, spacing=0.45, depth=1)
    base.rename(directory / "base.toml")
    path = directory / name
    path.write_text(
        SWEEP.format(planners=json.dumps(PLANNERS), throws=THROWS, feints=FEINTS, seed=SEED,
                     mix=MIX, chunk=chunk)
    )  # fmt: skip
    return path


def without_seconds(summary: dict) -> str:
    """A bench summary as canonical JSON without its only timing field and without where it ran
    (the bench command's tree fingerprint, machine and versions)."""
    from thinkfast.sim.bench_cli import PROVENANCE

    drop = {"seconds", *PROVENANCE}
    return json.dumps({k: v for k, v in summary.items() if k not in drop}, sort_keys=True)


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory) -> Path:
    """A directory with the sweep file (``sweep.toml``) and its base compile config."""
    d = tmp_path_factory.mktemp("sweep")
    write_sweep(d)
    return d


@pytest.fixture(scope="module")
def reference(sweep_dir):
    """Serial runs: every point's tree compiled with the compiler in a test process (once per
    source state: the tests' tree cache) and benched by run_bench with one process, summarized
    as ``thinkfast-sim bench`` does; per point index: (tree fingerprint, summary JSON without
    seconds)."""
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.bench import run_bench, summarize
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World
    from thinkfast.sweep.spec import compile_text, load_sweep
    from thinkfast.tree.file import load_tree, tree_fingerprint

    spec = load_sweep(sweep_dir / "sweep.toml")
    d = sweep_dir / "serial"
    d.mkdir()
    trees, out = {}, {}
    for p in spec.points:
        if p.tree_key not in trees:
            cfg = d / f"{p.tree_key[:8]}.toml"
            cfg.write_text(compile_text(p.compile_config, spec.robot_path))
            trees[p.tree_key] = compile_cached(cfg, d / f"{p.tree_key[:8]}.h5")
        tree = load_tree(trees[p.tree_key])
        world = World(tree, load_robot(), p.run_config, ServoConfig(), CameraModelConfig())
        rows = run_bench(lambda w=world: w, spec.throws, PLANNERS, SEED, jobs=1)
        summary = summarize(rows, PLANNERS, None)
        summary["seed"] = SEED
        out[p.index] = (tree_fingerprint(tree), without_seconds(summary), trees[p.tree_key])
    return out


@pytest.fixture(scope="module")
def local_run(sweep_dir):
    """The sweep through an embedded Dask cluster of 2 worker processes."""
    from thinkfast.sim.cluster import open_client
    from thinkfast.sweep.report import write_results
    from thinkfast.sweep.run import run_sweep
    from thinkfast.sweep.spec import load_sweep
    from thinkfast.sweep.store import SweepStore

    spec = load_sweep(sweep_dir / "sweep.toml")
    store = SweepStore(sweep_dir / "local")
    with open_client("local", 2) as client:
        report = run_sweep(spec, store, client)
    write_results(spec, store, report.docs)
    return spec, store, report


def _worker_dirs() -> set[Path]:
    return set(Path(tempfile.gettempdir()).glob("thinkfast-*"))


def test_a_sweep_on_a_two_worker_local_cluster_equals_serial_benches(local_run, reference):
    from thinkfast.tree.file import load_tree, tree_fingerprint

    spec, store, report = local_run
    assert not report.failures
    assert (report.trees_compiled, report.chunks_computed) == (2, 8)  # 2 trees, 4 x 2 chunks
    assert len({p.tree_key for p in spec.points}) == 2  # [run] values share a tree
    for p in spec.points:
        fingerprint, summary, _ = reference[p.index]
        assert tree_fingerprint(load_tree(store.tree_path(p.tree_key))) == fingerprint
        assert without_seconds(report.docs[p.index]["summary"]) == summary, p.params
    table = json.loads((store.root / "results.json").read_text())
    assert [d["params"] for d in table["points"]] == [p.params for p in spec.points]
    csv = (store.root / "results.csv").read_text().splitlines()
    assert csv[0].startswith("point,compile.tree.eps,run.launch.window,planner,throws,blocked")
    assert len(csv) == 1 + 4 * len(PLANNERS)
    oracle = [r for r in csv[1:] if ",oracle," in r]
    assert all(",tree," in r for r in oracle)  # its paired difference names the reference


def test_the_bench_command_gives_the_sweep_points_result(reference):
    """``thinkfast-sim bench`` (serial, its own throws from --throws/--seed/--mix/--feints) on
    point 0's tree (default runtime config: launch.window 6) prints the reference summary."""
    _, summary, tree = reference[0]
    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(tree), "--throws", str(THROWS), "--seed",
        str(SEED), "--mix", MIX, "--feints", str(FEINTS), "--planners", ",".join(PLANNERS),
        "--json", "--jobs", "1",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert without_seconds(json.loads(proc.stdout)) == summary


def test_a_rerun_computes_only_what_is_missing(local_run, reference, tmp_path):
    from thinkfast.sim.cluster import open_client
    from thinkfast.sweep.run import run_sweep
    from thinkfast.sweep.store import SweepStore

    spec, store, _ = local_run
    copy = SweepStore(tmp_path / "copy")
    shutil.copytree(store.root, copy.root)
    with open_client("serial", 1) as client:
        again = run_sweep(spec, copy, client)
        assert (again.points_from_disk, again.chunks_computed, again.trees_compiled) == (4, 0, 0)
        p = spec.points[2]
        copy.point_path(p.point_key).unlink()
        copy.chunk_path(p.point_key, 1, THROWS + FEINTS).unlink()
        before = copy.chunk_path(p.point_key, 0, 1).stat().st_mtime_ns
        third = run_sweep(spec, copy, client)
    assert (third.points_from_disk, third.chunks_from_disk, third.chunks_computed) == (3, 1, 1)
    assert copy.chunk_path(p.point_key, 0, 1).stat().st_mtime_ns == before  # not recomputed
    assert without_seconds(third.docs[2]["summary"]) == reference[2][1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def loopback_cluster(tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes (no nanny: a killed worker stays
    dead) on 127.0.0.1; yields (address, worker processes)."""
    import distributed

    dask = str(Path(sys.executable).parent / "dask")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    log = open(tmp_path / "dask.log", "w")  # noqa: SIM115
    procs = [
        subprocess.Popen(
            [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )  # fmt: skip
    ]
    try:
        for name in ("wA", "wB"):
            procs.append(
                subprocess.Popen(
                    [
                        dask,
                        "worker",
                        addr,
                        "--nthreads",
                        "1",
                        "--no-nanny",
                        "--no-dashboard",
                        "--name",
                        name,
                        "--host",
                        "127.0.0.1",
                    ],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=env,
                )  # fmt: skip
            )
        deadline = time.monotonic() + 60
        while True:
            try:
                with distributed.Client(addr, timeout=5) as c:
                    c.wait_for_workers(2, timeout=max(1.0, deadline - time.monotonic()))
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)
        yield addr, procs[1:]
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()


def test_a_separate_cluster_runs_bench_and_a_sweep_that_survives_a_killed_worker(
    loopback_cluster, reference, tmp_path
):
    """Not ``realtime``: nothing here runs on a schedule. The kill follows an event (the first
    point's file), the results are compared exactly, the waits only give up (60 s, 120 s) and
    a loaded host only makes the sweep slower, which leaves more of it after the kill. It runs
    in the parallel step with the module's other tests, sharing their serial ``reference``."""
    addr, workers = loopback_cluster
    dirs_before = _worker_dirs()
    _, summary0, tree0 = reference[0]
    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(tree0), "--throws", str(THROWS), "--seed",
        str(SEED), "--mix", MIX, "--feints", str(FEINTS), "--planners", ",".join(PLANNERS),
        "--json", "--scheduler", addr, "--chunk", "1",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert without_seconds(json.loads(proc.stdout)) == summary0

    from thinkfast.sweep.spec import load_sweep
    from thinkfast.sweep.store import SweepStore

    directory = tmp_path / "s"
    directory.mkdir()
    path = write_sweep(directory)
    spec = load_sweep(path)
    out = SweepStore(tmp_path / "out")
    for p in spec.points:  # the serial run's trees (the same ones): only benches remain
        out.tree_path(p.tree_key).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(reference[p.index][2], out.tree_path(p.tree_key))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("THINKFAST_DEBUG", None)
    sweep = subprocess.Popen(
        [sys.executable, "-c", "from thinkfast.sweep.cli import main; main()", "sweep", str(path),
         "-o", str(out.root), "--scheduler", addr, "--json", "--no-png"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
    )  # fmt: skip
    first = out.point_path(spec.points[0].point_key)
    deadline = time.monotonic() + 60
    while not first.exists():
        assert sweep.poll() is None, sweep.communicate()
        assert time.monotonic() < deadline, "no point finished in 60 s"
        time.sleep(0.02)
    finished = {p.point_key: p for p in spec.points if out.point_path(p.point_key).exists()}
    stamps = {k: out.point_path(k).stat().st_mtime_ns for k in finished}
    chunks_then = len(list((out.root / "chunks").rglob("*.json")))
    workers[0].send_signal(signal.SIGKILL)
    stdout, stderr = sweep.communicate(timeout=120)
    assert workers[0].wait(timeout=10) == -signal.SIGKILL
    assert chunks_then < 4 * (THROWS + FEINTS), "the sweep was over before the kill"
    assert sweep.returncode == 0, stderr
    for k in finished:  # a finished point is never recomputed
        assert out.point_path(k).stat().st_mtime_ns == stamps[k]
    results = json.loads(stdout)
    assert len(results["points"]) == 4
    for doc in results["points"]:
        assert without_seconds(doc["summary"]) == reference[doc["index"]][1], doc["params"]
    # workers leave nothing on disk (one killed with SIGKILL could remove nothing): trees are
    # read in memory
    assert _worker_dirs() - dirs_before == set()


def test_sweep_files_are_checked_key_by_key(tmp_path):
    from thinkfast.errors import ConfigError
    from thinkfast.sweep.spec import load_sweep

    path = write_sweep(tmp_path)
    text = path.read_text()
    path.write_text(text.replace("tree.eps = [0.1, 0.15]", "tree.epss = [0.1]"))
    proc = run_cli("thinkfast-sim", "sweep", str(path), "--scheduler", "serial")
    assert_one_line_error(proc, str(path), "compile.tree.epss", "unknown key")
    cases = {
        "tree.eps = [0.1, -1.0]": "compile.tree.eps",
        "tree.eps = 0.1": "compile.tree.eps",  # not an array of values
        "tree.eps = [0.1, 0.15, 0.2]\n[sweep2]": "sweep2",
        "plane.distance = [0.8, 1.0]": "compile.plane.distance",  # one cell per sweep (paired)
        "goals.y_max = [0.9, 0.6]": "compile.goals.y_max",
    }
    for new, key in cases.items():
        path.write_text(text.replace("tree.eps = [0.1, 0.15]", new))
        with pytest.raises(ConfigError) as err:
            load_sweep(path)
        assert err.value.key == key and err.value.source == str(path), str(err.value)
    path.write_text(text.replace('mix = "', 'mode = "list"\nmix = "').replace("[6, 8]", "[6]"))
    with pytest.raises(ConfigError, match="sweep.mode: list mode needs as many values"):
        load_sweep(path)
    path.write_text(text.replace('mix = "', 'mode = "list"\nmix = "'))
    assert [p.params for p in load_sweep(path).points] == [
        {"compile.tree.eps": 0.1, "run.launch.window": 6},
        {"compile.tree.eps": 0.15, "run.launch.window": 8},
    ]


def test_the_example_and_benchmark_sweeps_load():
    from thinkfast.sweep.spec import load_sweep

    example = load_sweep(ROOT / "examples" / "SWEEP.toml")
    assert (len(example.points), len({p.tree_key for p in example.points})) == (8, 4)
    timed = load_sweep(ROOT / "bench" / "sweep_4x200.toml")
    assert len({p.tree_key for p in timed.points}) == 4 and timed.settings.throws == 200


def test_an_embedded_cluster_leaves_this_processs_environment_as_it_was():
    """Dask's nannies set thread limits (OMP_NUM_THREADS=1, ...) for their workers in the
    parent's os.environ; left there, every process started afterwards (a bench, a compile)
    ran with one BLAS thread and recorded another machine than this one."""
    import os

    from thinkfast.sim.cluster import open_client

    before = dict(os.environ)
    with open_client("local", 1) as client:
        assert client is not None
    assert dict(os.environ) == before
