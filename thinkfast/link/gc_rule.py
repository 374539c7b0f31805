"""Garbage collection where it cannot delay a reply: the heap built at start frozen (never
scanned again), automatic collection off, and the interpreter's own rule (its thresholds)
applied by hand between replies. One rule for the daemon's loop, its reply process and the
decision benchmark, so the benchmark times what the daemon does."""

from __future__ import annotations

import gc


def hold() -> None:
    """Collect once, freeze what survives (the tree, the set-up) and turn automatic collection
    off; :func:`collect_due` then collects between replies."""
    gc.collect()
    gc.freeze()
    gc.disable()


def release() -> None:
    """Undo :func:`hold`: automatic collection on, the frozen heap scanned again."""
    gc.enable()
    gc.unfreeze()


def collect_due(oldest: int = 2) -> None:
    """Collect the generation the interpreter would collect now (none below its generation-0
    threshold), at most generation ``oldest``."""
    counts, limits = gc.get_count(), gc.get_threshold()
    if counts[0] < limits[0]:
        return
    generation = 0 if counts[1] < limits[1] else 1 if counts[2] < limits[2] else 2
    gc.collect(min(generation, oldest))
