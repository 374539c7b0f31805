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
) -> None:
    """A simulated IRC5 on this machine: RWS over HTTP (thinkfast-cell) and EGM over UDP to the
    daemon while the kit's RAPID program is in a session (docs/CELL.md, rehearsal)."""
    import logging
    import signal

    from thinkfast.config import from_dict, load_toml
    from thinkfast.daemon.egm_address import parse_hostport
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.irc5 import SimIrc5

    target = parse_hostport(egm, "--egm")
    host, port = parse_hostport(rws, "--rws")
    cfg = ServoConfig() if servo is None else from_dict(ServoConfig, load_toml(servo), servo)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("thinkfast.sim.controller").setLevel(logging.ERROR)  # overrun chatter
    irc5 = SimIrc5(target, host, port, cfg, q0=load_robot().home)
    if motors_off:
        irc5.rws.ctrlstate = "motoroff"
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _f: stopping.append(signum))
    irc5.start()
    print(f"simulated IRC5: RWS on {irc5.url} (user 'Default User', password 'robotics'), "
          f"EGM to {target[0]}:{target[1]} in a session; Ctrl-C ends", flush=True)  # fmt: skip
    try:
        irc5.run(lambda: bool(stopping))
    finally:
        irc5.close()
    print("simulated IRC5 stopped", flush=True)
