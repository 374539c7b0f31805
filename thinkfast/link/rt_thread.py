"""Real-time settings of the daemon's EGM thread: a CPU of its own and SCHED_FIFO (Linux).

Both apply to the calling thread only, after zenoh has started its threads: those move to the
other CPUs and keep the normal policy, so they never take the EGM loop's core or priority.
"""

from __future__ import annotations

import os
import threading

from thinkfast.errors import ThinkfastError


class RealtimeError(ThinkfastError):
    """The OS refused a real-time setting; the message says which option and why."""


def pin_thread(cpu: int) -> None:
    """Run the calling thread on ``cpu`` alone and the process's other (already started)
    threads on the other usable CPUs.

    Raises:
        RealtimeError: ``cpu`` is not one of the usable CPUs.
    """
    usable = os.sched_getaffinity(0)
    if cpu not in usable:
        names = ", ".join(str(c) for c in sorted(usable))
        raise RealtimeError(f"--cpu: {cpu} is not one of the usable CPUs {names}")
    others = usable - {cpu}
    me = threading.get_native_id()
    os.sched_setaffinity(0, {cpu})
    if not others:
        return
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:  # no procfs: the other threads stay where they are
        return
    for tid in tids:
        if tid != me:
            try:
                os.sched_setaffinity(tid, others)
            except OSError:  # the thread has just ended
                pass


def set_fifo(priority: int) -> None:
    """Put the calling thread under SCHED_FIFO at ``priority`` (1..99).

    A thread that never sleeps must not run under SCHED_FIFO: the kernel throttles real-time
    threads that use a whole CPU (``/proc/sys/kernel/sched_rt_runtime_us``), stopping them for
    tens of milliseconds every second.

    Raises:
        RealtimeError: the priority is out of range, or the OS refuses (no CAP_SYS_NICE).
    """
    if not 1 <= priority <= 99:
        raise RealtimeError(f"--fifo: priority {priority} is not in 1..99")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:
        raise RealtimeError(
            f"--fifo {priority}: SCHED_FIFO refused ({exc}); run with CAP_SYS_NICE (or as "
            "root), or without --fifo"
        ) from None
