"""Recording targets (missing, read-only, full) and the soak run.

Missing and read-only targets must be refused at start-up: one line on stderr, a non-zero exit,
and not a single reply served before (an EGM sender runs from the daemon's start). A full disk is
simulated with ``RLIMIT_FSIZE`` (``SIGXFSZ`` ignored) in the daemon's process: it must keep
serving, exit 0 on SIGINT, and leave a partial record that h5py opens. A read-only target as
root (who writes anywhere) is an immutable directory (``chattr +i``).
"""

from __future__ import annotations

import os
import resource
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path

from bench.faultkit.cell import Cell
from bench.faultkit.egm_pb import robot_message
from bench.faultkit.scenario import (
    Result,
    blocked_summary,
    easy_throw,
    error_result,
    finish,
    sampled_throws,
    scenario,
)
from bench.faultkit.senders import free_udp_port, recv_stamped
from thinkfast.contract.zenoh_session import free_tcp_port
from thinkfast.sim.realtime import daemon_log, start_daemon

FSIZE_LIMIT = 64 * 1024  # bytes a "full disk" lets the daemon write


def _refused(name: str, ctx, target: Path, t_start: float):
    """Start the daemon recording to ``target`` with an EGM sender running; it must refuse."""
    egm, zport = free_udp_port(), free_tcp_port()
    proc = start_daemon(ctx.tree, "tree", egm, zport, f"rec{os.getpid()}", target, None,
                        ctx.daemon_opts)  # fmt: skip
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    sent = replies = 0
    deadline = time.time() + 10.0  # a refusing daemon exits within its start-up (~3 s)
    try:
        while proc.poll() is None and time.time() < deadline:
            sent += 1
            sock.sendto(robot_message(sent, 4 * sent, ctx.robot.home), ("127.0.0.1", egm))
            replies += sum(1 for _ in recv_stamped(sock))
            time.sleep(0.004)
        running = proc.poll() is None
        if running:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(15.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    finally:
        sock.close()
    err = [ln for ln in daemon_log(proc).splitlines() if ln.strip()]
    fig = {"exit": proc.returncode, "replies_served": replies, "stderr_lines": len(err),
           "stderr": err[-1][:160] if err else "", "seconds_to_exit": None if running else
           round(time.time() - t_start, 1)}  # fmt: skip
    fails = []
    if running:
        fails.append("kept running (not refused at start-up)")
    elif proc.returncode == 0:
        fails.append("exit status 0")
    if replies:
        fails.append(f"served {replies} replies before refusing")
    if len(err) != 1:
        fails.append(f"{len(err)} lines on stderr (want one)")
    if any("Traceback" in ln for ln in err):
        fails.append("traceback on stderr")
    return fig, fails


def _refusal(name: str, ctx, make_target):
    t_start = time.time()
    tmp = Path(tempfile.mkdtemp(prefix="faults-rec-"))
    undo = None
    try:
        target, undo = make_target(tmp)
        fig, fails = _refused(name, ctx, target, t_start)
        return Result(name, not fails, {"target": str(target), **fig}, fails,
                      round(time.time() - t_start, 1))  # fmt: skip
    except Exception as exc:
        return error_result(name, t_start, exc)
    finally:
        if undo is not None:
            undo()
        shutil.rmtree(tmp, ignore_errors=True)


def _missing(tmp: Path):
    return tmp / "no_such_dir" / "rec.h5", None


def _read_only(tmp: Path):
    d = tmp / "ro"
    d.mkdir()
    if os.geteuid() != 0:
        d.chmod(0o555)
        return d / "rec.h5", lambda: d.chmod(0o755)
    subprocess.run(["chattr", "+i", str(d)], check=True, capture_output=True)
    return d / "rec.h5", lambda: subprocess.run(["chattr", "-i", str(d)], capture_output=True)


scenario("record_missing", "--record into a directory that does not exist: refused at start-up")(
    lambda ctx, opts: _refusal("record_missing", ctx, _missing)
)
scenario("record_readonly", "--record into a read-only directory: refused at start-up")(
    lambda ctx, opts: _refusal("record_readonly", ctx, _read_only)
)


def _fsize_limit() -> None:  # runs in the daemon's process before exec
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, FSIZE_LIMIT))


@scenario("record_full", f"--record with {FSIZE_LIMIT // 1024} KB of disk left (RLIMIT_FSIZE)")
def record_full(ctx, opts):
    import h5py

    t_start = time.time()
    tmp = Path(tempfile.mkdtemp(prefix="faults-rec-"))
    target = tmp / "rec.h5"
    cell = Cell(ctx, record=target, preexec_fn=_fsize_limit, seed=ctx.seed)
    figures: dict = {}

    def opens(fig):  # after the daemon exited: its partial record must open
        figures["record_bytes"] = target.stat().st_size if target.exists() else None
        try:
            with h5py.File(target, "r") as f:
                figures["record_datasets"] = {
                    k: int(f[k].shape[0]) for k in f if isinstance(f[k], h5py.Dataset)
                }
        except Exception as exc:
            return [f"the partial record does not open: {type(exc).__name__}: {exc}"[:160]]
        return []

    try:
        cell.start()
        outs = [cell.throw(easy_throw(i), i) for i in range(1 if opts.quick else 3)]
        figures.update(blocked_summary(outs))
        fails = [] if all(o.executed for o in outs) else ["a throw was not executed"]
        return finish("record_full", cell, t_start, figures, fails, extra=opens, opts=opts)
    except Exception as exc:
        cell.close()
        return error_result("record_full", t_start, exc)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def soak(ctx, opts, minutes: float):
    """Throws every 3 s, the fuzz stream running, for ``minutes``; the daemon's RSS every 10 s
    (growth after the first fifth of the run: the warm-up)."""
    from bench.faultkit.sc_process import fuzz_result, start_fuzz

    t_start = time.time()
    tmp = Path(tempfile.mkdtemp(prefix="faults-soak-"))
    cell = Cell(ctx, record=tmp / "soak.h5" if opts.record else None, seed=ctx.seed)
    cell.keep_rows = False
    seconds, rss, stop = 60.0 * minutes, [], threading.Event()

    def sample() -> None:
        t0 = time.time()
        while not stop.wait(max(0.0, t0 + 10.0 * len(rss) - time.time())):
            rss.append((round(time.time() - t0, 1), cell.rss_mb()))

    try:
        cell.start()
        fz = start_fuzz(cell, int(50 * seconds), seconds, ctx.seed)  # 50 payloads/s on average
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        outs, t_loop, throws = [], time.time(), sampled_throws(ctx, 200)
        while time.time() - t_loop < seconds:
            i = len(outs)
            outs.append(cell.throw(throws[i % len(throws)], i, settle=0.0))
            cell.feed()  # the checker keeps up; rows are not kept
            time.sleep(max(0.0, t_loop + 3.0 * (i + 1) - time.time()))
        stop.set()
        sampler.join(1.0)
        fzr = fuzz_result(fz, 120.0)
        samples = [(t, m) for t, m in rss if m is not None]
        warm = [s for s in samples if s[0] >= max(30.0, 0.2 * seconds)]  # after the warm-up
        growth = span = None
        if len(warm) >= 2:
            growth, span = warm[-1][1] - warm[0][1], (warm[-1][0] - warm[0][0]) / 60.0
        fig = {
            **blocked_summary(outs),
            "minutes": minutes,
            "record": bool(opts.record),
            "fuzz_sent": fzr.get("sent"),
            "rss_mb": [(t, round(m, 1)) for t, m in samples],
            "rss_growth_after_warmup_mb": None if growth is None else round(growth, 1),
            "rss_growth_mb_per_min": None if growth is None else round(growth / span, 2),
        }
        return finish("soak", cell, t_start, fig, [], opts=opts)
    except Exception as exc:
        stop.set()
        cell.close()
        return error_result("soak", t_start, exc)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
