"""Fault campaign against the real ``thinkfast-run`` daemon: a hostile or faulty ABB cell.

Bench code, not part of the package: ``bench/faults.py`` runs it, ``tests/test_faults.py`` tests
its parts (both with the repository root on ``sys.path``).

* :mod:`.egm_pb`: ABB's ``egm.proto`` message classes, built independently of the daemon's;
* :mod:`.controller`: the fault-injecting controller (servo model on its own 250 Hz clock);
* :mod:`.senders`, :mod:`.flood`: malformed datagrams, a second sender, a bounded flood;
* :mod:`.fuzz`: hostile detection payloads over zenoh (a process of its own);
* :mod:`.checker`: independent checks of the applied commands, per controller cycle;
* :mod:`.monitor`, :mod:`.cell`: the daemon's status and setpoints; the cell around the daemon;
* :mod:`.probe`: host stall probe (attributes missed replies to the machine);
* :mod:`.scenario` and the ``sc_*`` modules: the scenarios run by ``bench/faults.py``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository: ``bench`` and ``thinkfast`` in it


def spawn(module: str, *args: str, **popen) -> subprocess.Popen:
    """Run ``bench.faultkit.<module>`` as a child process (``python -m``) with ``args``.

    The child runs in the repository root, which ``-m`` puts first on its ``sys.path``: it finds
    this package as the parent did, whatever else is called ``bench`` where the parent runs.
    ``popen``: more :class:`subprocess.Popen` arguments (pipes, text).
    """
    cmd = [sys.executable, "-m", f"{__name__}.{module}", *args]
    return subprocess.Popen(cmd, cwd=ROOT, **popen)
