"""robot.toml checked against its URDF and for plausibility, units above all.

robot.toml holds the limits the safety supervisor enforces, so a slip in it is a safety defect: a
velocity typed in deg/s (180 where 3.14 rad/s is meant) must not reach the daemon. The schema
(:class:`thinkfast.robot.model.RobotToml` through :func:`thinkfast.config.from_dict`) already
refuses wrong types, non-finite numbers and limits <= 0; these functions check what needs the
joint list or the URDF. :func:`thinkfast.robot.model.load_robot` runs them once, so the compiler,
the daemon, the simulators and calibration all refuse the same file with the same
:class:`~thinkfast.errors.ConfigError`: robot.toml, the key, the value and the fix.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence

import numpy as np

from thinkfast.errors import ConfigError

DEG = math.pi / 180.0  # rad per degree

# Plausibility bounds for the limits the URDF does not state (acceleration and jerk, and the
# velocity of a joint whose URDF <limit velocity> is 0). Each is several times the IRB 1600's
# fastest axis and well below its slowest typed in degrees, so what it refuses is a unit slip,
# not a fast robot. Raise one, with a comment, for a robot that really is faster.
MAX_VELOCITY = 30.0  # rad/s (1720 deg/s): 3.7x its fastest (8.03); slowest in deg/s: 180
MAX_ACCELERATION = 200.0  # rad/s^2: 5x its fastest (40, assumed); slowest in deg/s^2: 688
MAX_JERK = 5000.0  # rad/s^3: 12x its fastest (400, assumed); slowest in deg/s^3: 6875

# A velocity above the URDF's that is within this factor of the URDF's limit in deg/s "looks
# like deg/s" (the data sheet's 180 typed for 3.14 rad/s; 1.5 allows a rounded or other value).
# A home beyond this factor of its joint's largest limit, and inside them in degrees, likewise.
DEG_WINDOW = 1.5

PER_JOINT = ("home", "max_velocity", "max_acceleration", "max_jerk")


def check_lengths(cfg, source: str) -> None:
    """Every per-joint list of robot.toml (``home``, ``max_*``) has one value per ``joints``.

    Args:
        cfg: the parsed robot.toml (:class:`~thinkfast.robot.model.RobotToml`).
        source: robot.toml path, for messages.

    Raises:
        ConfigError: a list of another length (names the key).
    """
    n = len(cfg.joints)
    for key in PER_JOINT:
        got = len(getattr(cfg, key))
        if got != n and not (key == "home" and got == 0):  # no home: the compile config solves it
            raise ConfigError(
                source, key, f"expected {n} values, one per joint of joints "
                f"({', '.join(cfg.joints)}), got {got}",
            )  # fmt: skip


def check_limits(
    cfg, q_lower: np.ndarray, q_upper: np.ndarray, v_urdf: np.ndarray, source: str, urdf: str
) -> None:
    """robot.toml's velocity, acceleration and jerk limits and its home, against the URDF.

    Args:
        cfg: the parsed robot.toml, its lists as long as ``cfg.joints`` (:func:`check_lengths`).
        q_lower, q_upper: URDF position limits [rad], shape (n,), in ``cfg.joints`` order.
        v_urdf: URDF ``<limit velocity>`` [rad/s], shape (n,); 0 means the URDF states none.
        source: robot.toml path, for messages.
        urdf: URDF file name, for messages.

    Raises:
        ConfigError: a velocity above the URDF's (or, where the URDF states none, above
            :data:`MAX_VELOCITY`), an acceleration or jerk above its plausibility bound, or a
            home outside the URDF's position limits; names the key (``max_velocity[0]``), the
            value and the fix, with a deg hint when the value looks like degrees.
    """
    for i, joint in enumerate(cfg.joints):
        v, u = cfg.max_velocity[i], float(v_urdf[i])
        key = f"max_velocity[{i}]"
        if 0.0 < u < math.inf:
            if v > u * (1.0 + 1e-9):
                looks_deg = u / DEG / DEG_WINDOW <= v <= u / DEG * DEG_WINDOW
                fix = (
                    _deg_hint(v, "rad/s", _down(v * DEG))
                    if looks_deg
                    else f"robot.toml may only lower it: set at most {_down(u, 6)}"
                )
                raise ConfigError(
                    source, key, f"{v:g} rad/s is above {joint}'s URDF limit {u:.6g} rad/s "
                    f"(<limit velocity> in {urdf}); {fix}",
                )  # fmt: skip
        elif v > MAX_VELOCITY:
            raise ConfigError(source, key, _bound_problem(v, MAX_VELOCITY, "rad/s", joint))
        for name, bound, unit in (
            ("max_acceleration", MAX_ACCELERATION, "rad/s^2"),
            ("max_jerk", MAX_JERK, "rad/s^3"),
        ):
            x = getattr(cfg, name)[i]
            if x > bound:
                raise ConfigError(source, f"{name}[{i}]", _bound_problem(x, bound, unit, ""))
    for i, joint in enumerate(cfg.joints if cfg.home else ()):
        h, lo, hi = cfg.home[i], float(q_lower[i]), float(q_upper[i])
        if not lo <= h <= hi:
            far = abs(h) > DEG_WINDOW * max(abs(lo), abs(hi))  # a near miss is not degrees
            fix = (
                f"degrees? robot.toml takes rad: {h * DEG:.3g} for {h:g} deg"
                if far and lo <= h * DEG <= hi
                else "choose a home inside them (the robot's README, Home)"
            )
            raise ConfigError(
                source, f"home[{i}]", f"{h:g} rad is outside {joint}'s URDF limits "
                f"[{lo:.4g}, {hi:.4g}] rad; {fix}",
            )  # fmt: skip


def check_links(
    cfg, links: Collection[str], shield_links: Sequence[str], source: str, urdf: str
) -> None:
    """robot.toml's ``shield_link`` and ``allowed_collisions`` name links of the URDF.

    Args:
        cfg: the parsed robot.toml.
        links: every link name of the URDF.
        shield_links: the URDF links with exactly one cylinder collision (valid shields).
        source: robot.toml path, for messages.
        urdf: URDF file name, for messages.

    Raises:
        ConfigError: an unknown shield link (lists the valid ones) or an ``allowed_collisions``
            entry that is not two URDF links.
    """
    if cfg.shield_link not in links:
        raise ConfigError(
            source, "shield_link", f"{cfg.shield_link!r} is not a link of {urdf}; name the "
            f"link whose one cylinder collision is the shield (links of {urdf} with one "
            f"cylinder: {', '.join(shield_links) or 'none'})",
        )  # fmt: skip
    for i, pair in enumerate(cfg.allowed_collisions):
        unknown = [p for p in pair if p not in links]
        if len(pair) != 2 or unknown:
            why = f"{', '.join(map(repr, unknown))} not in {urdf}" if unknown else "not a pair"
            raise ConfigError(
                source, f"allowed_collisions[{i}]", f"{list(pair)} must name two links ({why})"
            )


def _bound_problem(x: float, bound: float, unit: str, joint: str) -> str:
    """``x`` above a plausibility bound, with the deg hint when ``x`` in degrees is plausible."""
    why = f"; {joint}'s URDF <limit velocity> is 0" if joint else ""
    fix = f"check the value and its unit ({unit})"
    if x * DEG <= bound:
        fix = _deg_hint(x, unit, f"{x * DEG:.3g}")
    return f"{x:g} {unit} is above the plausibility bound {bound:g} {unit}{why}; {fix}"


def _deg_hint(x: float, unit: str, in_rad: str) -> str:
    """``looks like deg/s; robot.toml takes rad/s: 3.14 for 180 deg/s`` for ``unit`` rad/s
    (``in_rad``: ``x`` degrees in ``unit``, as written)."""
    deg_unit = unit.replace("rad", "deg")
    return f"looks like {deg_unit}; robot.toml takes {unit}: {in_rad} for {x:g} {deg_unit}"


def _down(x: float, digits: int = 3) -> str:
    """``x`` to ``digits`` significant digits, rounded toward zero (so a limit it suggests is
    never above the one it was computed from)."""
    if x == 0.0 or not math.isfinite(x):
        return f"{x:g}"
    e = math.floor(math.log10(abs(x))) - digits + 1
    return f"{math.trunc(x / 10.0**e) * 10.0**e:.{digits}g}"
