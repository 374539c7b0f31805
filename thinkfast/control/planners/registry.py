"""Every planner of the executor, by name: the one list the CLIs, the sweeps and the simulators
read.

An :class:`Entry` names a planner class (``"module:Class"``, imported when first built, so
listing the names stays cheap; or the class itself) and the runtime settings it runs with
(dotted keys of the runtime config: the hedge variants are the tree planner with ``[hedge]
mode`` set). ``online`` planners run in the daemon (``thinkfast-run --planner``, ``thinkfast-sim
run --planner``); every planner runs in lockstep (``thinkfast-sim bench --planners``, sweeps).
The simulators add the oracles, which need the true throw (``thinkfast/sim/planners.py``).

Adding a planner: one module in this package with a :class:`~.base.Planner` subclass, and one
line in :data:`BUILTIN` (docs/ARCHITECTURE.md, Planners).
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from thinkfast.control.config import RunConfig
    from thinkfast.control.planners.base import Planner

_HERE = "thinkfast.control.planners"


class Entry(NamedTuple):
    """One registered planner.

    Attributes:
        name: what the CLIs, sweep files and records call it.
        planner: the :class:`~.base.Planner` subclass, or ``"module:Class"`` naming it.
        doc: a few words for the CLIs' help.
        online: the daemon may run it (False: lockstep only).
        settings: (dotted runtime-config key, value) pairs it runs with, e.g.
            ``(("hedge.mode", "mean"),)``.
    """

    name: str
    planner: str | type
    doc: str = ""
    online: bool = True
    settings: tuple[tuple[str, Any], ...] = ()

    def load(self) -> type[Planner]:
        """The planner class (imported on first use)."""
        if not isinstance(self.planner, str):
            return self.planner
        module, _, cls = self.planner.partition(":")
        return getattr(importlib.import_module(module), cls)

    def configure(self, cfg: RunConfig) -> RunConfig:
        """``cfg`` with this entry's settings."""
        for key, value in self.settings:
            cfg = _replace(cfg, key.split("."), value, key)
        return cfg


TREE = f"{_HERE}.tree:TreePlanner"
MPC, JPL = f"{_HERE}.mpc:MpcPlanner", f"{_HERE}.jpl:JplPlanner"
REST = f"{_HERE}.tree_rest:TreeRestPlanner"
# settings of the look-ahead variants (docs/DESIGN.md, "Preposterior values")
HT, TERMS = ("hedge.mode", "tree"), ("hedge.terminals", True)
LOOK = ("value.backup", "lookahead")
BUILTIN = (
    Entry("tree", TREE, "belief-space: the re-rooted choice"),
    Entry("tree-rest", REST, "the paper's at-rest values"),
    Entry("naive", f"{_HERE}.naive:NaivePlanner", "baseline: the nearest goal"),
    Entry("naive-paper", f"{_HERE}.naive_paper:NaivePaperPlanner", "the paper's baseline"),
    Entry("mpc", MPC, "fixed-time MPC (CasADi + IPOPT)"),
    Entry("mpc-soft", MPC, "mpc, [mpc] terminal soft", True, (("mpc.terminal", "soft"),)),
    Entry("jpl", JPL, "EKF + cubic prediction + SCP (OSQP)"),
    Entry("jpl-filter", JPL, "jpl, [jpl] predictor filter", True, (("jpl.predictor", "filter"),)),
    Entry("tree-hedge-none", TREE, "tree, [hedge] mode none", False, (("hedge.mode", "none"),)),
    Entry("tree-hedge-mean", TREE, "tree, [hedge] mode mean", False, (("hedge.mode", "mean"),)),
    Entry("tree-hedge-tree", TREE, "tree, [hedge] mode tree", False, (("hedge.mode", "tree"),)),
    Entry("tree-hedge-lookahead", TREE, "tree-hedge-tree, [value] lookahead", False, (HT, LOOK)),
    Entry("tree-hedge-edges", TREE, "tree-hedge-tree, [hedge] terminals", False, (HT, TERMS)),
    Entry(
        "tree-hedge-edges-lookahead",
        TREE,
        "tree-hedge-edges, [value] lookahead",
        False,
        (HT, TERMS, LOOK),
    ),
    Entry("tree-rest-lookahead", REST, "tree-rest, [value] backup lookahead", False, (LOOK,)),
)
_ENTRIES: dict[str, Entry] = {e.name: e for e in BUILTIN}


def names(online: bool = False) -> tuple[str, ...]:
    """Registered planner names, in registration order; ``online``: only the daemon's."""
    return tuple(n for n, e in _ENTRIES.items() if e.online or not online)


def get(name: str, online: bool = False) -> Entry:
    """The entry of ``name``.

    Raises:
        ValueError: ``name`` is not registered (or not online, with ``online``), listing the
            valid names.
    """
    valid = names(online)
    if name not in valid:
        raise ValueError(f"planner {name!r} is not one of {', '.join(valid)}")
    return _ENTRIES[name]


def describe(online: bool = True) -> str:
    """The planners with their docs, for a CLI's help: ``tree (belief-space: ...), ...``."""
    return ", ".join(f"{n} ({_ENTRIES[n].doc})" if _ENTRIES[n].doc else n for n in names(online))


def register(entry: Entry) -> None:
    """Add a planner at run time (tests, experiments).

    Raises:
        ValueError: the name is taken.
    """
    if entry.name in _ENTRIES:
        raise ValueError(f"planner {entry.name!r} is registered already")
    _ENTRIES[entry.name] = entry


def unregister(name: str) -> None:
    """Remove a planner added with :func:`register` (built-in ones stay)."""
    if any(e.name == name for e in BUILTIN):
        raise ValueError(f"planner {name!r} is built in")
    _ENTRIES.pop(name, None)


def _replace(obj: Any, path: list[str], value: Any, key: str) -> Any:
    """The frozen dataclass ``obj`` with the field at ``path`` (of the dotted ``key``) set to
    ``value``."""
    head = path[0]
    if not dataclasses.is_dataclass(obj) or head not in {f.name for f in dataclasses.fields(obj)}:
        raise ValueError(f"no runtime setting {key!r}")
    inner = value if len(path) == 1 else _replace(getattr(obj, head), path[1:], value, key)
    return dataclasses.replace(obj, **{head: inner})
