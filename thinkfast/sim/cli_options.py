"""Options and helpers shared by ``thinkfast-sim``'s commands: help texts, the cameras a run
sees with, and the throws it flies."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

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
        from thinkfast.view.live import parse_sink

        parse_sink(rerun)
    if foxglove is None:
        return () if rerun is None else ("--rerun", rerun)
    from thinkfast.errors import ConfigError
    from thinkfast.view.foxglove import foxglove_address

    foxglove_address(foxglove)
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


class TreePlane(NamedTuple):
    """Where a tree's throws are aimed: its plane ``x = plane_x`` [m] (the plane's frame) and
    its protected region (``aim_y``, ``aim_z``: (low, high) [m]; None: the throw model's);
    ``name`` is the tree's, for messages."""

    plane_x: float
    name: str
    aim_y: tuple[float, float] | None = None
    aim_z: tuple[float, float] | None = None


def tree_plane(meta, name: str) -> TreePlane:
    """The :class:`TreePlane` of the tree of ``meta`` (its provenance's plane and region).

    Raises:
        TreeFileError: the provenance is unreadable.
    """
    from thinkfast.tree.provenance import Provenance

    prov = Provenance.of(meta, name)
    aim_y, aim_z = prov.region
    return TreePlane(prov.plane_x, name, aim_y, aim_z)


def throw_config(mix: str | None, plane: float | TreePlane | None = None):
    """The throw model with the kinds of throw ``mix`` names (None: the default mix), aimed at
    ``plane``: a :class:`TreePlane` or its tuple (its plane and region), a plane x [m], or None (the
    model's default, 0.8 m and its region)."""
    import dataclasses

    from thinkfast.sim.thrower import parse_mix
    from thinkfast.sim.throws import ThrowConfig, aimed_at

    cfg = ThrowConfig()
    if isinstance(plane, tuple):  # a TreePlane, or its (plane x, name[, aim_y, aim_z])
        p = TreePlane(*plane)
        cfg = aimed_at(cfg, p.plane_x, p.aim_y, p.aim_z)
    elif plane is not None:
        cfg = aimed_at(cfg, plane)
    if mix is None:
        return cfg
    return dataclasses.replace(cfg, thrower=dataclasses.replace(cfg.thrower, mix=parse_mix(mix)))


def load_throws(
    n: int,
    seed: int,
    throw_set: Path | None,
    mix: str | None = None,
    feints: int = 0,
    plane: tuple[float, str] | None = None,
):
    """``n`` throws of ``seed`` (and ``feints`` feints) drawn, or the first ``n`` of a throw
    set (all with ``n`` 0).

    Args:
        plane: (plane x [m], the tree's name) the throws must be aimed at: drawn there, and a
            throw set aimed elsewhere is refused. None: the throw model's default plane.

    Raises:
        ConfigError: a bad option.
        ThinkfastError: the throw set cannot be read, or is aimed at another plane than the
            tree's (one line naming both).
    """
    from thinkfast.errors import ConfigError, ThinkfastError
    from thinkfast.sim.throws import sample_throws
    from thinkfast.sim.throwset import load_throw_set

    if feints < 0:
        raise ConfigError("--feints", None, f"must be >= 0, got {feints}")
    if throw_set is not None:
        if mix is not None or feints:
            raise ConfigError("--mix/--feints", None, "not with --throw-set (the set is given)")
        ts = load_throw_set(throw_set)
        throws = ts.throws[:n] if n else ts.throws
        if plane is not None:
            other = sorted({t.plane_x for t in throws if t.plane_x != plane[0]})
            if other:
                raise ThinkfastError(
                    f"{throw_set}: throws aimed at the plane x = {other[0]:g} m, but {plane[1]} "
                    f"was compiled for the plane x = {plane[0]:g} m: draw a throw set for it "
                    "(thinkfast-sim throws --tree)"
                )
        return throws
    return sample_throws(throw_config(mix, plane), n, seed, feints)


def tree_cell(path: Path, cfg=None):
    """The tree at ``path``, the robot it was compiled for and its plane, for a simulator.

    Args:
        path: the tree file.
        cfg: the run config (:class:`~thinkfast.control.config.RunConfig`; None: defaults);
            its ``robot``, when set, must be the tree's robot.

    Returns:
        (tree, robot, plane): the :class:`~thinkfast.tree.action_tree.ActionTree`, the checked
        :class:`~thinkfast.robot.model.Robot` and its :class:`TreePlane` for
        :func:`load_throws`.

    Raises:
        TreeFileError: the tree cannot be read.
        ConfigError, RobotModelError: the robot cannot be loaded or is not the tree's (one line
            naming both).
    """
    from thinkfast.tree.file import load_tree
    from thinkfast.tree.robot_match import robot_for_tree

    tree = load_tree(path)
    robot = robot_for_tree(tree.meta, str(path), cfg.robot if cfg is not None else None)
    return tree, robot, tree_plane(tree.meta, str(path))
