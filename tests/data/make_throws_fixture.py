"""Write the throw-set fixtures of format version 1 (``tests/data/throws_v1_seed7*.json``).

Made once with the code of commit cd9b2c4 (before the thrower model: every throw held still, then
released) and committed; never regenerate them (they are what old files and old motions look
like). ``tests/test_sim_thrower.py`` checks that today's code reads the set as ``still`` throws
and draws the same throws, with the same ball motion, bit for bit.

    thinkfast-sim throws -o tests/data/throws_v1_seed7.json --throws 12 --seed 7
    python tests/data/make_throws_fixture.py tests/data/throws_v1_seed7.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from thinkfast.sim.throws import ball_states, load_throw_set


def main() -> None:
    src = Path(sys.argv[1])
    out = src.with_name(src.stem + "_states.json")
    rows = []
    for th in load_throw_set(src).throws:
        t = np.linspace(-th.t_release, th.flight_time + 0.05, 17)
        p, v = ball_states(th, t)
        rows.append({"id": th.id, "t": t.tolist(), "p": p.tolist(), "v": v.tolist()})
    out.write_text(json.dumps({"source": src.name, "states": rows}) + "\n", encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
