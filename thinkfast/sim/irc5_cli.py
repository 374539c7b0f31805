"""``thinkfast-sim controller``: the simulated IRC5 (:mod:`thinkfast.sim.irc5`) until Ctrl-C."""

from __future__ import annotations

from pathlib import Path

import typer

from thinkfast.cli_util import ZENOH_CONFIG, ZenohConfigFile


def controller(
    egm: str = typer.Option(
        "127.0.0.1:6510", "--egm", help="HOST:PORT of the daemon's EGM socket (thinkfast-run)"
    ),
    rws: str = typer.Option("127.0.0.1:8080", "--rws", help="HOST:PORT to serve RWS on"),
    servo: str | None = typer.Option(None, "--servo", help="TOML of ServoConfig keys"),
    motors_off: bool = typer.Option(False, "--motors-off", help="start with the motors off"),
    throws: int = typer.Option(
        0, "--throws", help="once a session runs, throw this many simulated balls (--zenoh)"
    ),
    zenoh: str | None = typer.Option(
        None,
        "--zenoh",
        help="with --throws: the daemon's zenoh endpoint to connect to (tcp/HOST:PORT; "
        "tls/HOST:PORT with a secured --zenoh-config)",
    ),
    zenoh_config: ZenohConfigFile = ZENOH_CONFIG,
    key_prefix: str = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix"),
    seed: int = typer.Option(1, "--seed", help="with --throws: throw and camera-noise seed"),
    config: str | None = typer.Option(
        None,
        "--config",
        help="the daemon's run config: its camera pose (with --throws) and "
        "its robot, which must be the tree's",
    ),
    tree: Path | None = typer.Option(
        None,
        "--tree",
        help="the daemon's tree: the arm is its robot (home, servo limits) and "
        "throws aim at its plane (default: the run config's robot, else the default robot)",
    ),
    kit: Path | None = typer.Option(
        None,
        "--kit",
        help="the controller kit loaded (its controller/ folder): the program homes to its "
        "TF_HOME, EGM caps joint speeds at its EGM_MAX_SPEED_DEV; refused when its home is "
        "not the tree's",
    ),
) -> None:
    """A simulated IRC5 on this machine: RWS over HTTP (thinkfast-cell) and EGM over UDP to the
    daemon while the kit's RAPID program is in a session (docs/CELL.md, rehearsal); with
    --throws, simulated balls thrown at the daemon once a session runs, each judged from the
    simulated arm (one line per throw, then a summary). On a secured cell (docs/SECURITY.md)
    the throws go out as the camera's node: --zenoh-config its camera-<id>.json5 (thinkfast-cell
    certs), --zenoh the daemon's TLS endpoint."""
    import logging
    import signal
    import threading

    from thinkfast.errors import ConfigError
    from thinkfast.link.egm_address import parse_hostport
    from thinkfast.sim.irc5 import SimIrc5

    target = parse_hostport(egm, "--egm")
    host, port = parse_hostport(rws, "--rws")
    if throws < 0 or (throws > 0 and zenoh is None):
        raise ConfigError("--throws", None, "a count >= 0; with throws, give --zenoh")
    if zenoh_config is not None:  # a bad file: one line now, not once a session runs
        from thinkfast.contract.zenoh_session import session_config

        session_config(config_file=zenoh_config)
    robot, cfg, plane = controller_cell(tree, config, servo, kit)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("thinkfast.sim.controller").setLevel(logging.ERROR)  # overrun chatter
    irc5 = SimIrc5(target, host, port, cfg, q0=robot.home)
    if motors_off:
        irc5.rws.ctrlstate = "motoroff"
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _f: stopping.append(signum))
    irc5.start()
    print(f"simulated IRC5: RWS on {irc5.url} (user 'Default User', password 'robotics'), "
          f"EGM to {target[0]}:{target[1]} in a session; Ctrl-C ends", flush=True)  # fmt: skip
    print(f"simulated arm: {robot.name} ({robot.toml_path}), at home "
          f"{[round(float(x), 4) for x in robot.home]} rad"
          + (f", throws at the plane x = {plane[0]:g} m of {plane[1]}" if plane else ""),
          flush=True)  # fmt: skip
    thrower = None
    if throws > 0:
        thrower = threading.Thread(
            target=_throw,
            args=(irc5, robot, throws, zenoh, zenoh_config, key_prefix, seed, config, plane,
                  stopping),
            daemon=True,
        )  # fmt: skip
        thrower.start()
    try:
        irc5.run(lambda: bool(stopping))
    finally:
        irc5.close()
    print("simulated IRC5 stopped", flush=True)


def controller_cell(
    tree: Path | None, config: str | None, servo: str | None, kit: Path | None = None
):
    """The simulated arm of ``thinkfast-sim controller``: (robot, servo model, plane).

    Args:
        tree: the daemon's tree (None: the run config's robot, else the default robot).
        config: the daemon's run config (its ``robot``, when set, must be the tree's).
        servo: TOML of :class:`~thinkfast.sim.controller.ServoConfig` keys (None: defaults);
            limits it leaves out are the robot's.
        kit: the controller kit's folder (None: a kit made for this robot and home is
            assumed): its home must be the robot's (the tree's), within :data:`KIT_HOME_TOL`;
            its EGM speed cap bounds the simulated arm's joint speeds, as on the controller.

    Returns:
        The :class:`~thinkfast.robot.model.Robot` (its ``home`` is where the arm starts), the
        :class:`~thinkfast.sim.controller.ServoConfig` with that robot's limits, and (plane x
        [m], the tree's name) for the throws (None without a tree: the throw model's plane).

    Raises:
        ConfigError, RobotModelError, TreeFileError: a bad file, or a robot that is not the
            tree's (one line naming both).
    """
    from thinkfast.config import from_dict, load_toml
    from thinkfast.control.config import load_run_config
    from thinkfast.sim.controller import ServoConfig, servo_for

    cfg = load_run_config(config)
    if tree is not None:
        from thinkfast.sim.cli_options import tree_cell

        _, robot, plane = tree_cell(tree, cfg)
    else:
        from thinkfast.robot.model import load_robot

        robot, plane = load_robot(Path(cfg.robot) if cfg.robot else None), None
        robot.require_home("pass --tree: the tree names the home the arm starts at")
    model = ServoConfig() if servo is None else from_dict(ServoConfig, load_toml(servo), servo)
    limits = servo_for(robot, model, str(servo or "servo"))
    if kit is not None:
        limits = _with_kit(robot, limits, kit, tree)
    return robot, limits, plane


KIT_HOME_TOL = 1e-5  # rad: the kit's TF_HOME holds 4 decimals of a degree (5e-5 deg = 9e-7 rad)


def _with_kit(robot, servo, kit: Path, tree: Path | None):
    """``servo`` with the kit's EGM speed cap, after checking the kit homes the arm to the
    robot's (the tree's) home.

    Raises:
        ConfigError: the kit's home is another (names both, and the command that makes the
            right kit).
    """
    import dataclasses

    import numpy as np

    from thinkfast.compile.kit import read_kit
    from thinkfast.errors import ConfigError

    settings = read_kit(kit)
    home = np.asarray(settings.home)
    if home.shape != robot.home.shape or np.max(np.abs(home - robot.home)) > KIT_HOME_TOL:
        deg = lambda q: [round(float(np.degrees(x)), 4) for x in q]  # noqa: E731
        fix = f" --tree {tree}" if tree is not None else ""
        raise ConfigError(
            str(kit), "TF_HOME", f"the kit homes the arm to {deg(home)} deg, but "
            f"{tree or robot.toml_path}'s home is {deg(robot.home)} deg: the daemon would find "
            f"the arm away from home; generate the kit for it: thinkfast-compile kit "
            f"{robot.toml_path}{fix}",
        )  # fmt: skip
    cap = settings.max_speed_deviation
    return dataclasses.replace(servo, v_max=tuple(min(float(v), cap) for v in servo.v_max))


def _throw(
    irc5, robot, n, zenoh: str, zenoh_config, prefix: str, seed: int, config, plane, stopping
) -> None:
    """The thrower beside the controller's loop: waits for a session, throws, prints."""
    from thinkfast.control.config import load_run_config
    from thinkfast.sim.cli_options import throw_config
    from thinkfast.sim.throws import sample_throws

    balls = sample_throws(throw_config(None, plane), n, seed=seed)
    cam = load_run_config(config).camera
    report = lambda line: print(line, flush=True)  # noqa: E731
    try:
        res = irc5.throw_in_session(robot, balls, zenoh, prefix, seed, cam, report,
                                    lambda: bool(stopping), zenoh_config)  # fmt: skip
    except Exception as exc:  # the thrower's failure ends the throws, not the controller
        print(f"throws stopped: {exc}", flush=True)
        return
    if res:
        k = sum(r.blocked for r in res)
        print(f"blocked {k} / {len(res)} simulated throws", flush=True)
