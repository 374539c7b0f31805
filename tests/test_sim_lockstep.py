"""Lockstep simulation and statistics: deterministic, paired, the oracle is the physical limit."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import ROBOT_TOML, assert_one_line_error, compile_small_tree, run_cli
from thinkfast.sim.bench import run_bench, summarize
from thinkfast.sim.bench_cli import PROVENANCE
from thinkfast.sim.lockstep import World, simulate
from thinkfast.sim.stats import wilson


@pytest.fixture(scope="module")
def tree_path(tmp_path_factory):
    return compile_small_tree(tmp_path_factory.mktemp("lockstep"))


class _Factory:
    def __init__(self, path):
        self.path = path

    def __call__(self):
        from thinkfast.control.config import RunConfig
        from thinkfast.robot.model import load_robot
        from thinkfast.sim.camera import CameraModelConfig
        from thinkfast.sim.controller import ServoConfig
        from thinkfast.tree.file import load_tree

        return World(
            load_tree(self.path),
            load_robot(ROBOT_TOML),
            RunConfig(),
            ServoConfig(),
            CameraModelConfig(),
        )


def _central_slow_throw():
    from thinkfast.sim.throws import ThrowConfig, make_throw

    return make_throw(ThrowConfig(), np.array([7.8, 0.1, 1.4]), (0.15, 1.1), 0.8, 0.5, "central")


def test_every_planner_blocks_a_slow_throw_near_home(tree_path):
    world = _Factory(tree_path)()
    throw = _central_slow_throw()
    for planner in ("oracle", "naive", "tree"):
        out = simulate(world, throw, planner, seed=3)
        assert out.blocked, (planner, out)
        if planner != "oracle":
            assert out.start > 0.0  # never before the release
    far = simulate(world, throw._replace(aim=np.array([0.9, 0.3])), "oracle", seed=3)
    assert far.throw_id == "central"


def test_a_long_held_ball_never_starts_the_arm_and_the_throw_still_does(tree_path):
    """6 balls held 3 s (about 900 frames with the camera model's outliers and dropouts)."""
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    world = _Factory(tree_path)()
    for th in sample_throws(ThrowConfig(hold_time=(3.0, 3.0)), 6, seed=8):
        out = simulate(world, th, "naive", seed=int(th.id.split("-")[1]))
        assert out.moved and 0.05 < out.start < 0.35, (th.id, out.start)


def test_oracle_seen_leaves_when_the_first_flight_detection_arrives(tree_path):
    from thinkfast.control.config import RunConfig
    from thinkfast.sim.camera import CameraModelConfig, observe
    from thinkfast.sim.lockstep import LEAD

    world = _Factory(tree_path)()
    throw = _central_slow_throw()
    seen = simulate(world, throw, "oracle_seen", seed=3)
    t_rel = LEAD + throw.t_release
    dets = observe(throw, CameraModelConfig(), RunConfig().camera, np.random.default_rng(3), t_rel)
    first = min(d.delivery_time for d in dets if d.capture_stamp > t_rel) - t_rel
    # it moves on the first 4 ms tick at or after that delivery (the latency is 30-60 ms)
    assert first <= seen.start < first + 0.0041 and seen.start >= 0.03
    assert seen.blocked  # a slow throw near home: still in time


def test_wilson_interval_matches_the_textbook_values():
    lo, hi = wilson(74, 100)  # centre (p + z^2/2n) / (1 + z^2/n) = 0.7311, half-width 0.0848
    assert abs(lo - 0.6463) < 1e-4 and abs(hi - 0.8160) < 1e-4
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == pytest.approx(1.0)


PLANNERS = ["tree", "naive", "oracle"]
BENCH = {"throws": 4, "seed": 2, "mix": "still=0.5,windup=0.5", "feints": 1}


@pytest.fixture(scope="module")
def bench_rows(tree_path):
    """The throws of ``thinkfast-sim bench`` with :data:`BENCH` (4 still and wind-up throws and
    a feint, drawn as the command draws them) flown in this process: (throws, rows)."""
    from thinkfast.sim.cli_options import load_throws

    b = BENCH
    throws = load_throws(b["throws"], b["seed"], None, b["mix"], b["feints"])
    return throws, run_bench(_Factory(tree_path), throws, PLANNERS, seed=b["seed"], jobs=1)


def test_lockstep_runs_are_deterministic_and_paired(tree_path, bench_rows):
    """The bench's throws flown again with 2 processes: the same rows, bit for bit."""
    throws, a = bench_rows
    b = run_bench(_Factory(tree_path), throws, PLANNERS, seed=BENCH["seed"], jobs=2)
    assert str(a) == str(b)  # same results for any number of processes (NaN-safe compare)
    assert [o.throw_id for o in a[::3]] == [t.id for t in throws]
    s = summarize(a, PLANNERS)
    assert (s["throws"], s["feints"]) == (4, 1)
    for entry in s["planners"].values():
        assert entry["blocked"] == sum(x["blocked"] for x in entry["by_flight_time"])
        assert 0.0 <= entry["rate_of_feasible"] <= 1.0
    assert s["planners"]["oracle"]["rate_of_feasible"] == 1.0


@pytest.fixture(scope="module")
def bench_json(tree_path, bench_rows):
    """The bench command's JSON for :data:`BENCH` with 2 processes, and the summary of the same
    throws flown in this process with one (as the command summarizes them)."""
    args = [f"--{k}={v}" for k, v in BENCH.items()]
    proc = run_cli(
        "thinkfast-sim", "bench", "--tree", str(tree_path), *args, "--planners",
        ",".join(PLANNERS), "--json", "--jobs", "2",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    one = summarize(bench_rows[1], PLANNERS)
    one["seed"] = BENCH["seed"]
    return one, json.loads(proc.stdout)


def test_bench_command_prints_one_json_object_identical_for_any_number_of_jobs(bench_json):
    """The command with 2 processes prints what one process computes for the same throws."""
    one, two = bench_json[0], dict(bench_json[1])
    assert two["throws"] == 4 and two["feints"] == 1
    for p in PLANNERS:
        e = two["planners"][p]
        assert {"blocked", "rate", "rate_of_feasible", "starts_before_release"} <= set(e)
        assert e["starts_before_release"] == sum(
            x["starts_before_release"] for k, x in e["by_kind"].items() if k != "feint"
        )
        assert e["feint_starts"] == e["by_kind"]["feint"]["starts"]
    assert two.pop("seconds") >= 0 and "seconds" not in one  # the only timing field
    for key in PROVENANCE:  # where it ran (tree, cell, machine), not what it measured
        two.pop(key)
    assert json.dumps(one, sort_keys=True) == json.dumps(two, sort_keys=True)


def test_bench_json_says_which_tree_machine_and_libraries_it_ran_with(bench_json, tree_path):
    from thinkfast.machine import library_versions, machine_info
    from thinkfast.sim.bench_cli import PROVENANCE
    from thinkfast.tree.file import load_tree, tree_fingerprint

    two = bench_json[1]
    assert set(PROVENANCE) <= set(two)
    assert two["tree_fingerprint"] == tree_fingerprint(load_tree(tree_path))
    here = machine_info()
    assert {k: two["machine"][k] for k in ("cpu", "blas", "numpy_simd", "env")} == {
        k: here[k] for k in ("cpu", "blas", "numpy_simd", "env")
    }
    assert two["versions"] == library_versions()


def test_bench_json_pairs_every_planner_with_tree_consistently(bench_json):
    """Counts add up to the paired throws; the paired rates are the planners' own rates (every
    released throw is paired); kinds and flight-time bins partition the throws."""
    s = bench_json[1]
    paired = s["paired"]
    assert paired["reference"] == "tree" and set(paired["planners"]) == {"naive", "oracle"}
    cells = ("both", "only_reference", "only_other", "neither")
    for p, e in paired["planners"].items():
        o = e["overall"]
        assert sum(o[c] for c in cells) == o["throws"] == s["throws"]
        assert o["rate_reference"] == pytest.approx(s["planners"]["tree"]["rate"])
        assert o["rate_other"] == pytest.approx(s["planners"][p]["rate"])
        assert o["difference"] == pytest.approx(o["rate_other"] - o["rate_reference"])
        lo, hi = o["ci95"]
        assert lo <= o["difference"] <= hi and 0.0 <= o["p_exact"] <= 1.0
        for part in (list(e["by_kind"].values()), e["by_flight_time"]):
            for c in (*cells, "throws"):
                assert sum(x[c] for x in part) == o[c], (p, c)
        for k, x in e["by_kind"].items():
            assert x["throws"] == s["kinds"][k]
            assert x["rate_other"] == pytest.approx(s["planners"][p]["by_kind"][k]["rate"])
    assert set(paired["planners"]["naive"]["by_kind"]) == {"still", "windup"}


def test_bench_command_refuses_bad_planners_and_files(tree_path, tmp_path):
    assert_one_line_error(
        run_cli("thinkfast-sim", "bench", "--tree", str(tree_path), "--planners", "magic"),
        "--planners",
    )
    assert_one_line_error(
        run_cli(
            "thinkfast-sim",
            "bench",
            "--tree",
            str(tree_path),
            "--throws",
            "2",
            "--planners",
            "tree,naive",
            "--reference",
            "oracle_seen",
        ),  # fmt: skip
        "--reference",
    )
    bad = tmp_path / "x.h5"
    bad.write_text("no")
    assert_one_line_error(run_cli("thinkfast-sim", "bench", "--tree", str(bad)), str(bad))


def test_wind_ups_and_a_feint_run_end_to_end_and_are_reported_per_kind(
    tree_path, bench_rows, tmp_path
):
    """The bench's still throws, wind-ups and feint (:data:`BENCH`), every planner: each kind
    has its own entry, the kinds add up to the planner's figures, and the oracle (which never
    leaves for a feint) leaves a wind-up's flight as it leaves its still twin's."""
    import dataclasses

    from thinkfast.sim.bench import format_summary, plot_summary
    from thinkfast.sim.cli_options import throw_config
    from thinkfast.sim.throws import sample_throws

    throws, out = bench_rows
    s = summarize(out, PLANNERS)
    kinds = s["kinds"]
    assert set(kinds) == {"still", "windup", "feint"} and kinds["feint"] == 1
    assert (s["throws"], s["feints"]) == (4, 1) and kinds["still"] + kinds["windup"] == 4
    for e in s["planners"].values():
        assert set(e["by_kind"]) == {"still", "windup", "feint"}
        thrown = [e["by_kind"][k] for k in ("still", "windup")]
        for x, k in zip(thrown, ("still", "windup"), strict=True):
            assert {
                "throws",
                "blocked",
                "rate",
                "ci95",
                "starts_before_release",
                "rate_of_feasible",
            } <= set(x)
            assert x["throws"] == kinds[k]
        assert sum(x["blocked"] for x in thrown) == e["blocked"]
        f = e["by_kind"]["feint"]
        assert {"feints", "starts", "displacement_m", "displacement_max_m", "home_again"} <= set(f)
        assert f["feints"] == 1 and f["home_again"] <= 1
        assert 0.0 <= f["displacement_max_m"] < 3.0
    oracle = s["planners"]["oracle"]["by_kind"]["feint"]
    assert (
        oracle["starts"] == 0 and oracle["displacement_max_m"] == 0.0 and oracle["home_again"] == 1
    )
    text = format_summary(s)
    assert "windup" in text and "still" in text and "feints (never released)" in text
    plot_summary(s, str(tmp_path / "kinds.png"))
    assert (tmp_path / "kinds.png").stat().st_size > 10_000
    # the oracle leaves at the release: a wind-up's flight is its still twin's, bit for bit
    i = next(k for k, t in enumerate(throws) if t.kind == "windup")
    cfg = throw_config(None)
    still = dataclasses.replace(cfg, thrower=dataclasses.replace(cfg.thrower, mix=(1.0, 0.0, 0.0)))
    twin = sample_throws(still, i + 1, seed=BENCH["seed"])[i]
    world = _Factory(tree_path)()
    a, b = simulate(world, throws[i], "oracle", 5), simulate(world, twin, "oracle", 5)
    assert (a.blocked, a.miss_distance, a.kind, b.kind) == (
        b.blocked,
        b.miss_distance,
        "windup",
        "still",
    )


def test_lockstep_checks_the_arm_it_measures_like_the_daemon(tree_path):
    """The core is checked against the simulated controller's joints: an arm that cannot
    follow (a quarter of the planned acceleration) trips the supervisor's deviation brake in
    lockstep as on the wire; the arm the planner assumed never does."""

    from thinkfast.sim.controller import ServoConfig, servo_for

    world = _Factory(tree_path)()
    throw = _central_slow_throw()
    normal = simulate(world, throw, "naive", seed=3)
    assert normal.blocked and normal.intervened == 0 and normal.faults == 0
    weak = ServoConfig(a_max=tuple(0.25 * a for a in world.robot.a_max))
    world.servo = servo_for(world.robot, weak)
    lame = simulate(world, throw, "naive", seed=3)
    assert lame.moved and lame.intervened > 0, lame  # braked: the arm left its commands


def test_a_jittering_controller_clock_needs_no_supervisor_and_blocks_as_the_exact_one(tree_path):
    """A controller whose ``tm`` jitters +-1 ms, rounds to whole ms, repeats and jumps 10-50 ms
    (its servo advancing one cycle per packet): the core counts the cycles by ``seqno``, so the
    plan is sampled on the servo's clock and the supervisor changes fewer than 0.1 % of the
    ticks (judged by ``tm``: about 1 %, and throws lost), blocking what the exact clock blocks."""
    from thinkfast.sim.controller import ClockJitter
    from thinkfast.sim.lockstep import DT, LEAD
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    throws = sample_throws(ThrowConfig(), 8, seed=5)
    exact = _Factory(tree_path)()
    jitter = _Factory(tree_path)()
    jitter.clock = ClockJitter(stall_rate=2.0, seed=7)
    intervened, ticks, blocked = 0, 0, {"exact": 0, "jitter": 0}
    for i, th in enumerate(throws):
        a = simulate(exact, th, "tree", seed=i)
        b = simulate(jitter, th, "tree", seed=i)
        intervened += b.intervened
        ticks += int((LEAD + th.t_release + th.flight_time) / DT)  # fewer than were stepped
        blocked["exact"] += a.blocked
        blocked["jitter"] += b.blocked
        assert b.faults == 0
    assert intervened < 0.001 * ticks, (intervened, ticks)
    assert blocked["jitter"] == blocked["exact"], blocked
