"""What machine a measurement ran on (for benchmark tables and JSON)."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def machine_info() -> dict[str, str | int]:
    """CPU model, usable cores, Python and numpy versions, OS."""
    import numpy as np

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    return {
        "cpu": cpu,
        "cores": cores,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
    }
