"""Options and helpers shared by ``thinkfast-sim``'s commands: help texts, the cameras a run
sees with, and the throws it flies."""

from __future__ import annotations

from pathlib import Path

MIX_HELP = (
    "kinds of throw drawn, KIND=WEIGHT,... of still, windup, feint (default: "
    "thinkfast/sim/thrower.py DEFAULT_MIX: half still holds, half wind-ups)"
)
FEINTS_HELP = "feints appended to the drawn throws (ids s<seed>-f<j>)"
SCHEDULER_HELP = (
    "run as Dask tasks (docs/SWEEPS.md): local (an embedded cluster on this machine), serial "
    "(this process, no Dask) or a running scheduler's address, tcp://HOST:8786; same results"
)
RERUN_HELP = (
    "live view with Rerun: spawn, connect[=URL] or save=FILE.rrd (docs/LIVE_VIEW.md; needs the "
    "view extra)"
)

FOXGLOVE_HELP = (
    "live view in Foxglove: serve its WebSocket protocol on [HOST:]PORT (loopback by default; "
    "docs/LIVE_VIEW.md; needs the foxglove extra); not with --rerun"
)


CAMERAS_HELP = (
    "cameras that see the throws, comma separated: base (the run config's [camera]) first, then "
    "ids of its [[cameras]] or side (the default side camera, docs/CAMERAS.md); default: the "
    "run config's. Compare two set-ups by running the same --seed with each"
)


def live_view_args(rerun: str | None, foxglove: str | None) -> tuple[str, ...]:
    """The daemon's options for ``--rerun`` / ``--foxglove`` of a simulator, checked here (a bad
    value fails before the daemon starts).

    Raises:
        ConfigError: a bad sink or address, or both options (one live view at a time).
    """
    if rerun is not None:
        from thinkfast.daemon.live_view import parse_sink

        parse_sink(rerun)
    if foxglove is None:
        return () if rerun is None else ("--rerun", rerun)
    from thinkfast.daemon.foxglove_view import parse_hostport
    from thinkfast.errors import ConfigError

    parse_hostport(foxglove)
    if rerun is not None:
        raise ConfigError("--foxglove", None, "not with --rerun: one live view at a time")
    return ("--foxglove", foxglove)


def with_cameras(cfg, cameras: str | None):
    """``cfg`` seeing with the cameras ``cameras`` names (None: unchanged); see CAMERAS_HELP."""
    import dataclasses

    from thinkfast.errors import ConfigError
    from thinkfast.estimate.fusion import DEFAULT_CAMERA, SIDE_CAMERA

    if cameras is None:
        return cfg
    names = [c.strip() for c in cameras.split(",") if c.strip()]
    if not names or names[0] != DEFAULT_CAMERA or len(set(names)) != len(names):
        raise ConfigError("--cameras", None, f"{cameras!r}: base first, each camera once")
    known = {c.id: c for c in cfg.cameras}
    known.setdefault(SIDE_CAMERA.id, SIDE_CAMERA)
    bad = [n for n in names[1:] if n not in known]
    if bad:
        raise ConfigError("--cameras", None, f"{bad[0]!r} is not one of base, {', '.join(known)}")
    return dataclasses.replace(cfg, cameras=tuple(known[n] for n in names[1:]))


def throw_config(mix: str | None):
    """The throw model with the kinds of throw ``mix`` names (None: the default mix)."""
    import dataclasses

    from thinkfast.sim.thrower import parse_mix
    from thinkfast.sim.throws import ThrowConfig

    cfg = ThrowConfig()
    if mix is None:
        return cfg
    return dataclasses.replace(cfg, thrower=dataclasses.replace(cfg.thrower, mix=parse_mix(mix)))


def load_throws(n: int, seed: int, throw_set: Path | None, mix: str | None = None, feints: int = 0):
    """``n`` throws of ``seed`` (and ``feints`` feints) drawn, or the first ``n`` of a throw
    set (all with ``n`` 0)."""
    from thinkfast.errors import ConfigError
    from thinkfast.sim.throws import sample_throws
    from thinkfast.sim.throwset import load_throw_set

    if feints < 0:
        raise ConfigError("--feints", None, f"must be >= 0, got {feints}")
    if throw_set is not None:
        if mix is not None or feints:
            raise ConfigError("--mix/--feints", None, "not with --throw-set (the set is given)")
        ts = load_throw_set(throw_set)
        return ts.throws[:n] if n else ts.throws
    return sample_throws(throw_config(mix), n, seed, feints)
