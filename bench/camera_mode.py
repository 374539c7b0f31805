"""Camera mode, paired: the bench's throws seen in one ZED mode per run, then compared.

``run`` flies the bench's throws (``thinkfast-sim bench``'s: throw ``i`` of the seed is the same
throw in every mode) with the default camera in ``--mode MODE@FPS`` (the run config's
``[camera] mode`` and ``fps``: the simulated camera and the daemon's stereo noise model follow
it) and writes the outcomes as JSON lines, each planner labelled with the mode
(``tree VGA@100``). ``combine`` reads several runs and
prints the bench's summary paired against ``--reference`` (exact McNemar, Newcombe interval;
the camera noise draws differ by mode, which is the point).

    python bench/camera_mode.py run --mode HD720@50 --throws 300 --out rows/hd720.jsonl
    python bench/camera_mode.py run --mode VGA@100 --throws 300 --out rows/vga.jsonl
    python bench/camera_mode.py combine rows/hd720.jsonl rows/vga.jsonl \\
        --reference "tree HD720@50" [--json]

``--start``/``--stop`` fly a piece of the throws (each keeps its camera seed), written throw by
throw; ``combine`` takes pieces in any number, a later file's row of a throw replacing an
earlier one's (the first 300 throws of ``--throws 1000`` are those of ``--throws 300``, their
feints are not), and compares the throws every run flew (``dropped``: the others).

``--window N`` sets ``[launch] window`` (detections per launch fit at 50 fps, 6 by default; the
daemon keeps its time span at the camera's rate, 11 at 100 fps).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

from thinkfast.contract.camera_mode import check_camera_setup
from thinkfast.control.config import launch_window, load_run_config
from thinkfast.errors import ConfigError
from thinkfast.machine import machine_info
from thinkfast.sim.bench import format_summary, run_bench, run_chunk, summarize
from thinkfast.sim.cli import _throws, _WorldFactory
from thinkfast.sim.lockstep import Outcome

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"


def mode_config(config: str | None, spec: str, window: int | None):
    """The run config of ``config`` (None: defaults) with its camera in ``spec`` (MODE@FPS) and,
    given, ``[launch] window`` set to ``window``."""
    mode, _, fps = spec.partition("@")
    cfg = load_run_config(config)
    try:
        camera = dataclasses.replace(cfg.camera, mode=mode, fps=float(fps or cfg.camera.fps))
    except ValueError:
        raise ConfigError("--mode", None, f"{spec!r}: MODE@FPS, e.g. VGA@100") from None
    check_camera_setup(camera, "--mode")
    if window is not None:
        cfg = dataclasses.replace(cfg, launch=dataclasses.replace(cfg.launch, window=window))
    return dataclasses.replace(cfg, camera=camera)


def _run(a) -> None:
    cfg = mode_config(a.config, a.mode, a.window)
    label = f"{cfg.camera.mode}@{cfg.camera.fps:g}" + ("" if a.window is None else f" w{a.window}")
    balls = _throws(a.throws, a.seed, None, a.mix, a.throws // 10 if a.feints < 0 else a.feints)
    start = time.perf_counter()
    stop = len(balls) if a.stop is None else min(a.stop, len(balls))
    planners, make = a.planners.split(","), _WorldFactory(Path(a.tree), cfg)
    with open(a.out, "w", encoding="utf-8") as f:
        if a.start or a.stop is not None:  # a piece, written throw by throw (stop it any time)
            world, rows = make(), []
            for i in range(a.start, stop):  # throw i keeps its camera seed
                rows += _write(f, run_chunk(world, balls[i : i + 1], planners, a.seed, i), label)
        else:
            rows = _write(f, run_bench(make, balls, planners, a.seed, a.jobs), label)
    took = time.perf_counter() - start
    w = launch_window(cfg)
    print(f"{len(rows)} outcomes ({label}, launch fit of {w}) -> {a.out}, {took:.0f} s")


def _write(f, rows: list[Outcome], label: str) -> list[Outcome]:
    """Write ``rows`` as JSON lines, each planner labelled with the mode; returns them."""
    for o in rows:
        f.write(json.dumps(o._replace(planner=f"{o.planner} {label}")._asdict()) + "\n")
    f.flush()
    return rows


def _combine(a) -> None:
    keyed: dict[tuple[str, str], Outcome] = {}  # a later file's row of a throw replaces one
    for p in a.rows:
        with open(p, encoding="utf-8") as f:
            for line in f:
                if line.strip():
                    o = Outcome(**json.loads(line))
                    keyed[(o.throw_id, o.planner)] = o
    names = list(dict.fromkeys(planner for _, planner in keyed))
    ids = [{t for t, p in keyed if p == name} for name in names]
    common = set.intersection(*ids)  # the throws every run flew (pieces may stop early)
    rows = [o for (t, _), o in keyed.items() if t in common]
    summary = summarize(rows, names, a.reference or names[0])
    summary["runs"] = a.rows
    summary["dropped"] = {n: len(i - common) for n, i in zip(names, ids, strict=True)}
    summary["machine"] = machine_info()
    if a.json:
        print(json.dumps(summary, default=lambda x: None if math.isnan(x) else x))
    else:
        print(format_summary(summary))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="fly the throws in one camera mode")
    r.add_argument("--mode", default="HD720@50", help="MODE@FPS, e.g. VGA@100")
    r.add_argument("--window", type=int, default=None, help="[launch] window (default: mode's)")
    r.add_argument("--tree", default=str(DEFAULT_TREE))
    r.add_argument("--throws", type=int, default=300)
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--feints", type=int, default=-1, help="default: a tenth of --throws")
    r.add_argument("--mix", default=None)
    r.add_argument("--planners", default="tree")
    r.add_argument("--config", default=None, help="runtime config (TOML)")
    r.add_argument("--jobs", type=int, default=1)
    r.add_argument("--start", type=int, default=0, help="first throw of a piece (0-based)")
    r.add_argument("--stop", type=int, default=None, help="end of a piece (default: all)")
    r.add_argument("--out", required=True)
    c = sub.add_parser("combine", help="pair runs of several modes")
    c.add_argument("rows", nargs="+")
    c.add_argument("--reference", default=None, help="default: the first run's first planner")
    c.add_argument("--json", action="store_true")
    a = ap.parse_args()
    _run(a) if a.cmd == "run" else _combine(a)


if __name__ == "__main__":
    main()
