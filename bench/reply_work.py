"""The isolated reply loop's work per EGM reply, replayed packet by packet (load-independent).

One process plays both sides of ``thinkfast-run --reply-process`` and a controller, in turn and
without the wall clock, so that every run of the same arguments makes the same replies:

* a simulated controller whose arm follows every command exactly sends each cycle's
  ``EgmRobot`` (real protobuf EGM over real UDP on loopback, ``seqno`` and ``tm`` exact);
* the reply loop (:class:`~thinkfast.reply.process.ReplyLoop` with its
  :class:`~thinkfast.link.egm_server.EgmServer`) answers it; its clock is the simulated one;
* the planner side, as the planner process: an executor of the tree that makes the reply loop's
  replans and steps at each reply's controller time (the rows of the shared ring), takes the
  throws' detections as they are delivered and publishes its plan (shared memory) when it
  changes; a stream of sampled throws, one every ``--throw-period``.

Where in the cycle the planner's plan lands is drawn per cycle (``--seed``: uniform over the
4 ms): ``--prepare window`` prepares the next reply 1 ms before the packet is due, after the
plan when it landed earlier (the loop of 710bd20); ``--prepare loop`` runs the loop's own work
between packets (``ReplyLoop.between``, where it has one: prepare as soon as it can, again after
a plan) before and after the plan lands; ``--prepare never`` prepares nothing, the reference: a
reply computed when its packet comes. ``--compare FILE`` checks the replies bit for bit against
another run's ``--save FILE``.

Per reply: the CPU time of the reply process's thread (``time.thread_time_ns``) over
``EgmServer.poll`` (read, decode, the reply, encode, send: what the packet waits for), and the
server's own ``work`` figure (read -> reply ready, ``perf_counter``); and whether the reply was
the prepared one. CPU time is what the loop spends, not when: it does not depend on the other
processes of the host (it does on the CPU and its caches). Instruction counts, which depend on
nothing but the code: run it under callgrind (``_poll``).

    python bench/reply_work.py --throws 3 --prepare loop --json
    python bench/reply_work.py --prepare never --save /tmp/ref.npy
    python bench/reply_work.py --prepare loop --compare /tmp/ref.npy
"""

from __future__ import annotations

import argparse
import functools
import gc
import json
import os
import platform
import socket
import sys
import time
from pathlib import Path

import numpy as np

from thinkfast.contract.egm import decode_sensor, encode_robot
from thinkfast.control.assembly import CoreAssembly
from thinkfast.control.config import RunConfig
from thinkfast.control.plan import SIZE, executor_plan
from thinkfast.link.egm import open_egm
from thinkfast.link.egm_server import EgmServer
from thinkfast.link.registry import LinkSpec
from thinkfast.reply import process as reply_process
from thinkfast.reply.process import ReplyLoop
from thinkfast.reply.rows import CALL, COL, REPLY, WIDTH
from thinkfast.reply.shared_plan import RowRing, Seqlock
from thinkfast.robot.model import default_robot_path, load_robot
from thinkfast.sim.camera import CameraModelConfig, detection_payload, observe_cameras
from thinkfast.sim.lockstep import sim_cameras
from thinkfast.sim.throws import ThrowConfig, sample_throws
from thinkfast.tree.file import load_tree

DT = 0.004
DEFAULT_TREE = Path(__file__).resolve().parents[1] / "trees" / "irb1600_default.h5"
WINDOW = 0.001  # s before the packet: the loop of 710bd20 prepares from here (spin window)


class SimTime:
    """The ``time`` module as the reply loop sees it here: the simulated clock."""

    def __init__(self):
        self.now = 0.0

    def time(self) -> float:
        return self.now

    def monotonic(self) -> float:
        return self.now

    def __getattr__(self, name):
        return getattr(time, name)


class Planner:
    """The planner process's side: rows in, the executor's plan out (module doc)."""

    def __init__(self, parts: CoreAssembly, planner: str, block: Seqlock, ring: RowRing):
        self.ex = parts.executor(planner)
        self.core = parts.core(self.ex)
        self.block, self.ring = block, ring
        self.plan_id, self.epoch, self.key = 0, 0, None
        self.published = 0
        self.t_last = 0.0  # the controller time of the last reply row

    def rows(self) -> None:
        ex = self.ex
        for row in self.ring.take():
            kind, t = row[COL["type"]], float(row[COL["t"]])
            q, qd, qdd = row[COL["q"]], row[COL["qd"]], row[COL["qdd"]]
            if kind == CALL:
                self.epoch += 1
                name = int(row[COL["code"]])
                if name == 0:
                    ex.resync(q, qd, qdd, t)
                elif name == 1:
                    ex.start_from(q, t)
                elif name == 2:
                    ex.hold_fault(q, t)
                else:
                    ex.recover(q, t)
            elif kind == REPLY:
                self.t_last = t
            if kind == REPLY and row[COL["stepped"]]:
                ex.wrist.reset(q[3:], t, qd[3:], qdd[3:])
                ex.setpoint(t)

    def publish(self) -> bool:
        # when the plan vector changes (the planner process: when plan_key does; this runs on
        # the code before plan_key too)
        plan = executor_plan(self.ex, 0, self.epoch)
        key = plan.tobytes()
        if key == self.key:
            return False
        self.key = key
        self.plan_id += 1
        self.published += 1
        plan[0] = self.plan_id
        self.block.write(plan)
        return True


def run(args) -> dict:
    robot = load_robot(default_robot_path())
    cfg = RunConfig()
    parts = CoreAssembly(load_tree(args.tree), robot, cfg)
    block, ring = Seqlock(SIZE), RowRing(WIDTH)
    clock = SimTime()
    reply_process.time = clock  # the loop's clock is the simulated one
    loop = ReplyLoop(robot, cfg, block, ring, os.getppid())
    loop.link = open_egm(LinkSpec("127.0.0.1:0"), loop.reply)
    planner = Planner(parts, args.planner, block, ring)
    ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctl.bind(("127.0.0.1", 0))
    ctl.settimeout(2.0)
    target = loop.link.address
    throws = sample_throws(ThrowConfig(), args.throws, args.seed)
    cameras = sim_cameras(cfg, CameraModelConfig())
    dets = []
    for i, th in enumerate(throws):
        t_rel = 1.0 + i * args.throw_period + th.t_release
        dets += [(d.delivery_time, detection_payload(d))
                 for d in observe_cameras(th, cameras, args.seed + i, t_rel)]  # fmt: skip
    dets.sort(key=lambda d: d[0])
    n = int((1.0 + args.throws * args.throw_period) / DT)
    rng = np.random.default_rng(args.seed)
    between = getattr(loop, "between", None)
    if args.prepare == "loop" and between is None:
        raise SystemExit("--prepare loop: this ReplyLoop has no between(); use window")

    def loop_work(replied: bool) -> None:
        if args.prepare == "loop":
            between(replied, clock.now)
            return
        loop.after(replied)
        loop.watch_plan(clock.now)

    q_arm = robot.home.copy()
    cpu = np.zeros(n)
    work = np.zeros(n)
    prepared = np.zeros(n, bool)
    replies = np.zeros((n, 12))
    k_det = 0
    gc.collect()
    gc.disable()  # as the reply process: collected between packets, never inside a reply
    for k in range(n):
        t_pkt = k * DT
        # the planner's turn lands at a random phase of the cycle before this packet
        phase = t_pkt - DT + rng.uniform(0.0, DT)
        in_window = phase >= t_pkt - WINDOW
        if args.prepare == "window" and in_window and k > 0:
            clock.now = t_pkt - WINDOW
            loop.core.prepare()
        clock.now = max(phase, 0.0)
        planner.rows()
        while k_det < len(dets) and dets[k_det][0] <= clock.now:
            planner.core.on_detection(dets[k_det][1], None, planner.t_last + DT)
            k_det += 1
        planner.publish()
        planner.block.beat(clock.now)
        loop_work(False)
        if args.prepare == "window" and not in_window and k > 0:
            clock.now = t_pkt - WINDOW
            loop.core.prepare()
        clock.now = t_pkt + 1e-5  # received 10 us after it was sent
        ctl.sendto(encode_robot(k + 1, 4 * k, q_arm), target)
        p = loop.core._prepared
        ahead = p.ahead if p is not None and p.t == loop.core.t_next else None
        c0 = time.thread_time_ns()
        sent = functools.reduce(_poll, (loop.link,), 0)
        cpu[k] = 1e-9 * (time.thread_time_ns() - c0)
        if not sent:
            raise SystemExit(f"packet {k}: no reply")
        timing = loop.link.timing
        work[k] = timing.work_s[(timing.count - 1) % len(timing.work_s)]
        prepared[k] = (
            ahead is not None and ahead.result is not None and (loop.core.last.q is ahead.result[0])
        )
        cmd = decode_sensor(ctl.recvfrom(1024)[0])
        q_arm = np.array(cmd.q_rad)
        replies[k] = np.r_[loop.core.last.q, loop.core.last.qd]
        loop_work(True)
        if gc.get_count()[0] >= gc.get_threshold()[0]:
            gc.collect(0)
    gc.enable()
    loop.link.close()
    ctl.close()
    block.close()
    ring.close()
    skip = min(250, n // 10)
    cpu_us, work_us = 1e6 * cpu[skip:], 1e6 * work[skip:]
    out = {
        "prepare": args.prepare, "planner": args.planner, "throws": args.throws,
        "seed": args.seed, "replies": n - skip, "plans_published": planner.published,
        "prepared": int(prepared[skip:].sum()),
        "cpu_us": _stats(cpu_us), "cpu_us_prepared": _stats(cpu_us[prepared[skip:]]),
        "cpu_us_unprepared": _stats(cpu_us[~prepared[skip:]]),
        "work_us": _stats(work_us),
        "supervisor_changes": int(loop.core.sup.intervened), "epoch": loop.follower.epoch,
        "behind": loop.link.counters.behind, "catch_ups": loop.core.catch_ups,
        "mode": loop.core.mode(),
        "machine": platform.machine(), "python": platform.python_version(),
        "load_1min": round(os.getloadavg()[0], 2),
    }  # fmt: skip
    if args.save:
        np.save(args.save, replies)
    if args.compare:
        ref = np.load(args.compare)
        same = np.array_equal(ref.view(np.int64), replies.view(np.int64))
        out["compare"] = {"file": args.compare, "identical": bool(same),
                          "replies_differing": int((ref != replies).any(axis=1).sum())}  # fmt: skip
    return out


def _poll(_, egm: EgmServer) -> int:
    """``egm.poll()``, called through ``functools.reduce`` (a C function the reply path does
    not use) so that ``valgrind --tool=callgrind --collect-atstart=no
    --toggle-collect=functools_reduce`` counts the instructions of the replies alone."""
    return egm.poll()


def _stats(x: np.ndarray) -> dict | None:
    if not len(x):
        return None
    p50, p99, p999 = np.percentile(x, [50, 99, 99.9])
    return {"n": len(x), "p50": round(float(p50), 1), "p99": round(float(p99), 1),
            "p99.9": round(float(p999), 1), "max": round(float(x.max()), 1),
            "mean": round(float(x.mean()), 1)}  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", default=str(DEFAULT_TREE))
    ap.add_argument("--planner", default="tree")
    ap.add_argument("--throws", type=int, default=3)
    ap.add_argument("--throw-period", type=float, default=3.5, help="s between throws")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--prepare", choices=("loop", "window", "never"), default="loop")
    ap.add_argument("--save", help="write the replies (q, qd per reply) to this .npy")
    ap.add_argument("--compare", help="compare the replies with this --save file")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    out = run(args)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{'replies':<22}{out['replies']}  prepared {out['prepared']}  plans "
          f"{out['plans_published']}  ({out['prepare']}, {out['machine']}, load "
          f"{out['load_1min']})")  # fmt: skip
    print(f"{'us':<22}{'p50':>8}{'p99':>8}{'p99.9':>8}{'max':>8}")
    for key in ("cpu_us", "cpu_us_prepared", "cpu_us_unprepared", "work_us"):
        s = out[key]
        if s is not None:
            print(f"{key:<22}{s['p50']:>8}{s['p99']:>8}{s['p99.9']:>8}{s['max']:>8}")
    if "compare" in out:
        print(f"compare: {out['compare']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
