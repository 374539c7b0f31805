"""The tree planner with and without compiled branches among its options, paired on the same
throws (lockstep: the same result on any machine and load).

Runs ``thinkfast-sim bench``'s simulation twice, the ``tree`` planner with the runtime config as
given (``[choice] branches`` off by default) and with ``[choice] branches = true``, on the same
throws and camera noise; prints both rates, the discordant throws and the exact McNemar p (the
bench's own statistics, :func:`thinkfast.sim.stats.compare`), overall and by kind of throw.

    python bench/branches.py --tree trees/irb1600_default.h5 --throws 300 --seed 1 [--jobs 2]
        [--config RUN.toml] [--json]   # --json: one object with every throw's outcome
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thinkfast.control.config import load_run_config  # noqa: E402
from thinkfast.sim.bench import run_bench  # noqa: E402
from thinkfast.sim.cli import _throws, _WorldFactory  # noqa: E402
from thinkfast.sim.stats import compare  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=Path("trees/irb1600_default.h5"))
    ap.add_argument("--throws", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--config", type=Path, default=None)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    base = load_run_config(args.config)
    on = dataclasses.replace(base, choice=dataclasses.replace(base.choice, branches=True))
    balls = _throws(args.throws, args.seed, None, None, 0)
    runs, seconds = {}, {}
    off_cfg = dataclasses.replace(base, choice=dataclasses.replace(base.choice, branches=False))
    for label, cfg in (("off", off_cfg), ("on", on)):
        start = time.perf_counter()
        runs[label] = run_bench(
            _WorldFactory(args.tree, cfg), balls, ["tree"], args.seed, args.jobs
        )
        seconds[label] = round(time.perf_counter() - start, 1)
    off, new = runs["off"], runs["on"]
    assert [o.throw_id for o in off] == [o.throw_id for o in new]
    out = {"throws": len(balls), "seed": args.seed, "seconds": seconds, "paired": {}}
    for kind in (None, "still", "windup"):
        idx = [i for i, o in enumerate(off) if kind is None or o.kind == kind]
        cmp = compare([off[i].blocked for i in idx], [new[i].blocked for i in idx])
        out["paired"][kind or "all"] = cmp
    if args.json:
        out["outcomes"] = [
            {"id": a.throw_id, "kind": a.kind, "off": a.blocked, "on": b.blocked}
            for a, b in zip(off, new, strict=True)
        ]
        print(json.dumps(out))
        return 0
    print(f"tree planner, {len(balls)} throws (seed {args.seed}), branches off vs on:")
    for kind, c in out["paired"].items():
        print(
            f"  {kind:>6}: off {c['rate_reference']:.1%}  on {c['rate_other']:.1%}"
            f"  only off {c['only_reference']}  only on {c['only_other']}"
            f"  diff {100 * c['difference']:+.1f} points  p {c['p_exact']:.3g}"
        )
    print(f"  ({seconds['off']} s off, {seconds['on']} s on)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
