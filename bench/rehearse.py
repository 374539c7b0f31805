"""Each cell in real time: its generated kit, the real daemon and the simulated IRC5 (docs/CELL.md).

    python bench/rehearse.py [--throws 10] [--seed 1] TREE.h5 [TREE.h5 ...]

For every tree: `thinkfast-compile kit ROBOT.toml --tree TREE -o DIR` (the tree's robot and
home), then the three processes of docs/CELL.md's rehearsal on free loopback ports:
`thinkfast-run --tree TREE ...`, `thinkfast-sim controller --tree TREE --kit DIR --throws N
--zenoh ...` and `thinkfast-cell start`. Prints the controller's throw lines and summary and
the daemon's counts of `away_from_home` and supervisor interventions; real time on this host,
so the blocked counts depend on its load (printed at the end).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
ZENOH = ROOT / "thinkfast" / "sim" / "loopback_zenoh.json5"
sys.path.insert(0, str(ROOT))  # bench.faultkit


def until(pred, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.2)
    return False


def rehearse(tree: Path, throws: int, seed: int, workdir: Path, use_kit: bool = True) -> dict:
    from bench.faultkit.senders import free_udp_port
    from thinkfast.contract.zenoh_session import free_tcp_port
    from thinkfast.tree.file import load_meta
    from thinkfast.tree.robot_match import tree_robot_path

    meta = load_meta(tree)
    robot_toml = tree_robot_path(meta)
    kit = workdir / f"{tree.stem}.controller"
    subprocess.run([str(BIN / "thinkfast-compile"), "kit", str(robot_toml), "--tree", str(tree),
                    "-o", str(kit)], check=True, capture_output=True)  # fmt: skip
    egm, rws, zen = free_udp_port(), free_tcp_port(), free_tcp_port()
    log = tempfile.TemporaryFile(mode="w+")
    daemon = subprocess.Popen(
        [str(BIN / "thinkfast-run"), "--tree", str(tree), "--egm-bind", f"127.0.0.1:{egm}",
         "--egm-controller", "127.0.0.1", "--zenoh-listen", f"tcp/127.0.0.1:{zen}",
         "--zenoh-config", str(ZENOH)],
        stdout=subprocess.DEVNULL, stderr=log, text=True,
    )  # fmt: skip
    lines: list[str] = []
    ctl = subprocess.Popen(
        [str(BIN / "thinkfast-sim"), "controller", "--egm", f"127.0.0.1:{egm}", "--rws",
         f"127.0.0.1:{rws}", "--tree", str(tree), *(["--kit", str(kit)] if use_kit else []),
         "--throws", str(throws),
         "--seed", str(seed), "--zenoh", f"tcp/127.0.0.1:{zen}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    threading.Thread(target=lambda: lines.extend(ln.rstrip() for ln in ctl.stdout),
                     daemon=True).start()  # fmt: skip
    url = f"http://127.0.0.1:{rws}"
    state = [str(BIN / "thinkfast-cell"), "state", "--url", url]
    ok = until(lambda: subprocess.run(state, capture_output=True).returncode == 0, 60)
    time.sleep(2.0)  # the daemon's zenoh and EGM sockets up
    start = subprocess.run([str(BIN / "thinkfast-cell"), "start", "--url", url],
                           capture_output=True, text=True)  # fmt: skip
    done = (
        ok
        and start.returncode == 0
        and until(
            lambda: any(ln.startswith(("blocked ", "throws stopped")) for ln in lines),
            30 + 3 * throws,
        )
    )
    for p in (ctl, daemon):
        p.send_signal(signal.SIGINT)
    for p in (ctl, daemon):
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            p.kill()
    log.seek(0)
    text = log.read()
    return {
        "tree": tree.name,
        "robot": meta.get("robot_name"),
        "lines": [ln for ln in lines if ln.startswith(("throw ", "blocked ", "simulated arm"))],
        "done": done,
        "start": (start.stdout + start.stderr).strip(),
        "away_from_home": text.count("away_from_home"),
        "interventions": text.count("intervention"),
        "daemon_exit": daemon.returncode,
        "warnings": [ln for ln in text.splitlines() if " WARNING " in ln or " ERROR " in ln],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs="+", type=Path)
    ap.add_argument("--throws", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-kit", action="store_true", help="the simulated IRC5 without the kit")
    a = ap.parse_args()
    ok = True
    with tempfile.TemporaryDirectory(prefix="thinkfast-rehearse-") as d:
        for tree in a.trees:
            r = rehearse(tree.resolve(), a.throws, a.seed, Path(d), not a.no_kit)
            print(f"== {r['tree']} ({r['robot']}): done {r['done']}, daemon exit "
                  f"{r['daemon_exit']}, away_from_home lines {r['away_from_home']}, "
                  f"intervention lines {r['interventions']}")  # fmt: skip
            print("\n".join(r["lines"]))
            for w in r["warnings"][:8]:
                print(f"  daemon: {w[:240]}")
            ok &= r["done"] and r["daemon_exit"] == 0
    print(f"load average at the end: {[round(x, 2) for x in os.getloadavg()]}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
