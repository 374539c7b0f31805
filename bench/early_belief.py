"""How the early belief narrows: its crossing N(Y, Z, tau) at each flight detection, k = 1 on.

For each of the first ``--throws`` throws of the bench's set (seed ``--seed``), the base camera's
detections are fed in capture order to the launch detector (its stored detections are what the
hedge stage reads) and, from the first detection that left the hold, the early belief
(``[early]``, :mod:`thinkfast.estimate.early_belief`) gives a crossing; its standard deviations
in Y, Z and tau and the error of its mean against the true crossing are printed per k, with the
detection at which the launch detector confirmed. ``--png`` draws them (one line per throw).

    python bench/early_belief.py --throws 6 --png docs/early_belief.png [--json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from thinkfast.control.config import RunConfig
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.estimate import early_belief as eb
from thinkfast.estimate.launch import LaunchDetector
from thinkfast.robot.model import load_robot
from thinkfast.sim.camera import CameraModelConfig, observe
from thinkfast.sim.throws import ThrowConfig, plane_crossing, sample_throws
from thinkfast.tree.file import load_tree

DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"


def narrowing(throw, cfg: RunConfig, tree, seed: int) -> dict:
    """Per flight detection k: (k, std Y, std Z, std tau [m, m, s], error of Y, Z [m]) and
    the k at which the launch was confirmed."""
    dets = observe(throw, CameraModelConfig(), cfg.camera, np.random.default_rng(seed), 0.0)
    rot, pos = cfg.camera.rotation(), cfg.camera.translation()
    det = LaunchDetector(cfg.launch, cfg.filter, cfg.camera.xyz)
    cross = plane_crossing(throw)
    lo, hi = tree.goal_yz.min(axis=0), tree.goal_yz.max(axis=0)
    rows, confirmed = [], None
    for d in sorted(dets, key=lambda d: d.capture_stamp):
        launched = det.add(d.capture_stamp, rot @ d.position_camera + pos) is not None
        fit = eb.early_fit(list(det.points), cfg.early, tree.plane_x, lo, hi, cfg.filter.gravity)
        if fit is None or d.capture_stamp < 0.0:
            continue
        c = tree.crossing(fit.mean, fit.cov, cfg.filter.gravity)
        if not c.ok:
            continue
        sd = np.sqrt(np.diag(c.cov))
        err = c.mean[:2] - [cross.y, cross.z]
        rows.append([len(rows) + 1, *sd.tolist(), *err.tolist()])
        if launched and confirmed is None:
            confirmed = len(rows)
        if len(rows) >= 8:
            break
    return {"id": throw.id, "kind": throw.kind, "rows": rows, "confirmed_k": confirmed}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--throws", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tree", default=str(DEFAULT_TREE))
    ap.add_argument("--png", default=None)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    cfg = RunConfig()
    tree = runtime_tree(load_tree(a.tree), load_robot(None), cfg)
    throws = sample_throws(ThrowConfig(), a.throws, a.seed)
    out = [narrowing(t, cfg, tree, a.seed * 1000 + i) for i, t in enumerate(throws)]
    if a.json:
        print(json.dumps(out))
    else:
        print("throw  kind    k  std Y [m]  std Z [m]  std tau [s]  err Y [m]  err Z [m]")
        for o in out:
            for r in o["rows"]:
                mark = "  <- launch confirmed" if r[0] == o["confirmed_k"] else ""
                print(f"{o['id']:<6} {o['kind']:<6} {r[0]:>2} {r[1]:>9.3f} {r[2]:>10.3f} "
                      f"{r[3]:>12.3f} {r[4]:>+10.3f} {r[5]:>+10.3f}{mark}")  # fmt: skip
    if a.png:
        _plot(out, a.png)


def _plot(out: list, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for o in out:
        r = np.array(o["rows"])
        if not len(r):
            continue
        for ax, col in zip(axes, (1, 2, 3), strict=True):
            (line,) = ax.plot(r[:, 0], r[:, col], marker="o", label=f"{o['id']} ({o['kind']})")
            if o["confirmed_k"]:
                k = o["confirmed_k"]
                ax.plot([k], [r[k - 1, col]], "s", color=line.get_color(), ms=10, mfc="none")
    for ax, name in zip(axes, ("std Y [m]", "std Z [m]", "std tau [s]"), strict=True):
        ax.set(xlabel="flight detection k (square: launch confirmed)", ylabel=name)
        ax.set_yscale("log")
    axes[0].legend(fontsize=7)
    fig.suptitle("early belief: crossing std per flight detection (base camera)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    main()
