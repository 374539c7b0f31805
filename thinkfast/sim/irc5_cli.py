"""``thinkfast-sim controller``: the simulated IRC5 (:mod:`thinkfast.sim.irc5`) until Ctrl-C."""

from __future__ import annotations

import typer


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
        None, "--zenoh", help="with --throws: the daemon's zenoh endpoint (tcp/HOST:PORT)"
    ),
    key_prefix: str = typer.Option("thinkfast", "--key-prefix", help="zenoh key prefix"),
    seed: int = typer.Option(1, "--seed", help="with --throws: throw and camera-noise seed"),
    config: str | None = typer.Option(
        None, "--config", help="with --throws: the daemon's run config (its camera pose)"
    ),
) -> None:
    """A simulated IRC5 on this machine: RWS over HTTP (thinkfast-cell) and EGM over UDP to the
    daemon while the kit's RAPID program is in a session (docs/CELL.md, rehearsal); with
    --throws, simulated balls thrown at the daemon once a session runs, each judged from the
    simulated arm (one line per throw, then a summary)."""
    import logging
    import signal
    import threading

    from thinkfast.config import from_dict, load_toml
    from thinkfast.daemon.egm_address import parse_hostport
    from thinkfast.errors import ConfigError
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.irc5 import SimIrc5

    target = parse_hostport(egm, "--egm")
    host, port = parse_hostport(rws, "--rws")
    cfg = ServoConfig() if servo is None else from_dict(ServoConfig, load_toml(servo), servo)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("thinkfast.sim.controller").setLevel(logging.ERROR)  # overrun chatter
    if throws < 0 or (throws > 0 and zenoh is None):
        raise ConfigError("--throws", None, "a count >= 0; with throws, give --zenoh")
    robot = load_robot()
    irc5 = SimIrc5(target, host, port, cfg, q0=robot.home)
    if motors_off:
        irc5.rws.ctrlstate = "motoroff"
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _f: stopping.append(signum))
    irc5.start()
    print(f"simulated IRC5: RWS on {irc5.url} (user 'Default User', password 'robotics'), "
          f"EGM to {target[0]}:{target[1]} in a session; Ctrl-C ends", flush=True)  # fmt: skip
    thrower = None
    if throws > 0:
        thrower = threading.Thread(
            target=_throw, args=(irc5, robot, throws, zenoh, key_prefix, seed, config, stopping),
            daemon=True,
        )  # fmt: skip
        thrower.start()
    try:
        irc5.run(lambda: bool(stopping))
    finally:
        irc5.close()
    print("simulated IRC5 stopped", flush=True)


def _throw(irc5, robot, n: int, zenoh: str, prefix: str, seed: int, config, stopping) -> None:
    """The thrower beside the controller's loop: waits for a session, throws, prints."""
    from thinkfast.control.config import load_run_config
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    balls = sample_throws(ThrowConfig(), n, seed=seed)
    cam = load_run_config(config).camera
    report = lambda line: print(line, flush=True)  # noqa: E731
    try:
        res = irc5.throw_in_session(robot, balls, zenoh, prefix, seed, cam, report,
                                    lambda: bool(stopping))  # fmt: skip
    except Exception as exc:  # the thrower's failure ends the throws, not the controller
        print(f"throws stopped: {exc}", flush=True)
        return
    if res:
        k = sum(r.blocked for r in res)
        print(f"blocked {k} / {len(res)} simulated throws", flush=True)
