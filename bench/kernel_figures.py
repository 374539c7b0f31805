"""Time the small kernels whose speed the code's docstrings used to quote (docs/BENCHMARKS.md,
"Kernel figures the code refers to").

    .venv/bin/python bench/kernel_figures.py            # table
    .venv/bin/python bench/kernel_figures.py --json     # one JSON object

Each row times two ways of doing one thing, measured alternately in the same process (``--rounds``
rounds, each the best of 5 repeats of ``number`` calls), and prints the median over the rounds
per call and the ratio. On a loaded host read the ratios, not the absolute times.

- ``any``: ``count_nonzero(mask) > 0`` (the safety supervisor's ``any_true``) against
  ``mask.any()`` on 6 joints;
- ``subsample``: ``cv2.resize`` nearest neighbour against ``image[::s, ::s]`` copied, on an
  HD720 image (the colour search's coarse image, ``search_step`` s = 2 and 4);
- ``at_time``: one ``Trajectory.at_time`` call from Python against one sample of
  ``thinkfast.robot.batch_traj`` (200 trajectories x 100 times per batch call);
- ``wrist``: ``CoplanarWrist.solve_one`` against ``solve(q123[None])``;
- ``values``: one ``terminal_values`` update with ``time_points`` 96 against the default 64
  (122 goals, 10,000 terminal edges, a wide correlated belief);
- ``iso_disk``: building the isotropic disk table (once per process), alone.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import timeit
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thinkfast.machine import machine_info  # noqa: E402


def _per_call(fn, number: int) -> float:
    """Best of 5 repeats of ``number`` calls, per call [s]."""
    return min(timeit.repeat(fn, number=number, repeat=5)) / number


def _pair(a, b, number: int, rounds: int) -> tuple[float, float]:
    """Median per-call time [s] of ``a`` and of ``b``, measured alternately."""
    ta, tb = [], []
    for _ in range(rounds):
        ta.append(_per_call(a, number))
        tb.append(_per_call(b, number))
    return statistics.median(ta), statistics.median(tb)


def bench_any(rounds: int) -> dict:
    from thinkfast.control.safety_limits import any_true

    mask = np.zeros(6, dtype=bool)
    new, old = _pair(lambda: any_true(mask), lambda: mask.any(), 100_000, rounds)
    return {"name": "any", "new": "any_true", "old": "ndarray.any", "t_new": new, "t_old": old}


def bench_subsample(rounds: int, step: int) -> dict:
    import cv2

    img = np.random.default_rng(0).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    size = (1280 // step, 720 // step)
    new, old = _pair(
        lambda: cv2.resize(img, size, interpolation=cv2.INTER_NEAREST),
        lambda: np.ascontiguousarray(img[::step, ::step]),
        100,
        rounds,
    )
    name = f"subsample s={step}"
    return {"name": name, "new": "cv2.resize", "old": "slice copy", "t_new": new, "t_old": old}


def _trajectories(n: int, seed: int = 0):
    from ruckig import InputParameter, Ruckig, Trajectory

    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        inp = InputParameter(3)
        inp.current_position = rng.uniform(-1, 1, 3).tolist()
        inp.current_velocity = rng.uniform(-0.5, 0.5, 3).tolist()
        inp.target_position = rng.uniform(-1, 1, 3).tolist()
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = [3.0] * 3, [12.0] * 3, [120.0] * 3
        traj = Trajectory(3)
        Ruckig(3).calculate(inp, traj)
        out.append(traj)
    return out


def bench_at_time(rounds: int) -> dict:
    from thinkfast.robot.batch_traj import TrajectoryTable

    trajs = _trajectories(200)
    times = np.linspace(0.0, 1.0, 100)
    table = TrajectoryTable(trajs)
    owner, at = np.repeat(np.arange(len(trajs)), len(times)), np.tile(times, len(trajs))
    samples = len(owner)
    new, old = _pair(lambda: table.positions(owner, at), lambda: trajs[7].at_time(0.31), 20, rounds)
    return {
        "name": "at_time",
        "new": "batch_traj per sample",
        "old": "Trajectory.at_time",
        "t_new": new / samples,
        "t_old": old,
    }


def bench_wrist(rounds: int) -> dict:
    from thinkfast.robot.model import load_robot
    from thinkfast.robot.wrist import CoplanarWrist

    wrist = CoplanarWrist(load_robot())
    q, prev = np.array([0.2, 0.4, -0.3]), np.zeros(3)
    new, old = _pair(
        lambda: wrist.solve_one(q, prev), lambda: wrist.solve(q[None], prev), 2000, rounds
    )
    return {"name": "wrist", "new": "solve_one", "old": "solve (N = 1)", "t_new": new, "t_old": old}


def bench_values(rounds: int) -> dict:
    from thinkfast.decide.values import ValueConfig, layout, terminal_values

    rng = np.random.default_rng(1)
    gy, gz = np.meshgrid(np.linspace(-0.9, 0.9, 11), np.linspace(0.3, 1.8, 11))
    goals = np.column_stack([gy.ravel(), gz.ravel()])
    goals = np.vstack([goals, [[0.1, 1.1]]])
    term_goal = rng.integers(0, len(goals), 10_000)
    remaining = rng.uniform(0.2, 0.7, len(term_goal))
    mean = np.array([0.1, 1.0, 0.5])
    sd = np.array([0.5, 0.4, 0.1])
    corr = np.array([[1.0, 0.2, 0.9], [0.2, 1.0, 0.3], [0.9, 0.3, 1.0]])
    cov = corr * np.outer(sd, sd)
    lay64 = layout(goals, term_goal, 0.15, ValueConfig(time_points=64))
    lay96 = layout(goals, term_goal, 0.15, ValueConfig(time_points=96))
    new, old = _pair(
        lambda: terminal_values(lay96, mean, cov, remaining),
        lambda: terminal_values(lay64, mean, cov, remaining),
        50,
        rounds,
    )
    return {
        "name": "values",
        "new": "time_points 96",
        "old": "time_points 64",
        "t_new": new,
        "t_old": old,
    }


def bench_iso_disk(rounds: int) -> dict:
    from thinkfast.decide import iso_disk

    times = []
    for _ in range(rounds):
        iso_disk._tables.cache_clear()
        times.append(_per_call(iso_disk.warm_up, 1))
    t = statistics.median(times)
    return {"name": "iso_disk", "new": "table build", "old": "-", "t_new": t, "t_old": None}


def run(rounds: int) -> dict:
    rows = [
        bench_any(rounds),
        bench_subsample(rounds, 2),
        bench_subsample(rounds, 4),
        bench_at_time(rounds),
        bench_wrist(rounds),
        bench_values(rounds),
        bench_iso_disk(rounds),
    ]
    for r in rows:
        r["ratio_old_new"] = None if r["t_old"] is None else r["t_old"] / r["t_new"]
    return {
        "rows": rows,
        "rounds": rounds,
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "machine": machine_info(),
    }


def _us(t: float | None) -> str:
    return "-" if t is None else f"{1e6 * t:.3f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds (median over them)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    out = run(args.rounds)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{'row':<16} {'new':<22} {'us':>10} {'old':<18} {'us':>10} {'old / new':>9}")
    for r in out["rows"]:
        ratio = "-" if r["ratio_old_new"] is None else f"{r['ratio_old_new']:.2f}"
        print(
            f"{r['name']:<16} {r['new']:<22} {_us(r['t_new']):>10} {r['old']:<18} "
            f"{_us(r['t_old']):>10} {ratio:>9}"
        )
    print(f"load average {out['load_average']}, {out['machine']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
