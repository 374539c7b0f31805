"""Every planner the simulators fly, from one place: the executor's registry
(:mod:`thinkfast.control.planners.registry`) and the lockstep oracles, which need the true throw
(:mod:`thinkfast.sim.lockstep`).

``oracle`` knows the true crossing point at release and goes there as fast as the arm allows
(the throws it blocks are the feasible ones); ``oracle_seen`` leaves only when the first
detection of the flight is delivered.
"""

from __future__ import annotations

from thinkfast.control.planners import registry
from thinkfast.errors import ConfigError

ORACLES = ("oracle", "oracle_seen")
DEFAULT = ("tree", "naive", "naive-paper", *ORACLES)
"""What ``thinkfast-sim bench`` and sweeps run when no planners are named."""


def lockstep_planners() -> tuple[str, ...]:
    """Every planner the lockstep simulator flies: the registry's, then the oracles."""
    return (*registry.names(), *ORACLES)


def online_planners() -> tuple[str, ...]:
    """The planners the daemon runs (``thinkfast-run --planner``, ``thinkfast-sim run``)."""
    return registry.names(online=True)


def check_planners(names, source: str | None, key: str, online: bool = False) -> None:
    """Refuse planner ``names`` that are not registered (the daemon's only, with ``online``).

    Raises:
        ConfigError: naming ``source`` and ``key`` and listing the valid names.
    """
    valid = online_planners() if online else lockstep_planners()
    bad = [n for n in names if n not in valid]
    if bad or not names:
        what = f"{bad[0]!r} is not one of" if bad else "name at least one of"
        raise ConfigError(source, key, f"{what} {', '.join(valid)}")
