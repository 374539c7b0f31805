"""EGM addresses as the command lines give them: the socket to bind (``HOST:PORT``) and the
controller to answer (``IP`` or ``IP:PORT``), checked with an error that shows the expected form."""

from __future__ import annotations

import ipaddress

from thinkfast.errors import ThinkfastError


class EgmAddressError(ThinkfastError):
    """A ``HOST:PORT`` or controller IP string is unusable; the message shows the expected form."""


def parse_hostport(
    text: str,
    what: str = "--egm-bind",
    default_host: str | None = None,
    example: str = "0.0.0.0:6510, 127.0.0.1:6511, [::1]:6510",
) -> tuple[str, int]:
    """``"HOST:PORT"`` (or ``"[IPv6]:PORT"``; ``"PORT"`` or ``":PORT"`` with ``default_host``) ->
    ``(host, port)``: the one parser of the command lines' socket addresses.

    Args:
        text: the address string; port 0 asks the OS for a free port.
        what: name of the option, for the error message.
        default_host: the host of a bare ``PORT`` (None: a host is required).
        example: valid forms shown in the error message.

    Raises:
        EgmAddressError: no colon (without ``default_host``), empty host, or a port that is not
            an integer in 0..65535.
    """
    text = str(text).strip()
    host, sep, port_s = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if default_host is not None and not host:
        host, sep = default_host, ":"  # "PORT" or ":PORT"
    if not sep or not host or not port_s.isdigit() or not 0 <= int(port_s) <= 65535:
        form = "HOST:PORT" if default_host is None else "[HOST:]PORT"
        raise EgmAddressError(f"{what}: {text!r} is not {form} (e.g. {example})")
    return host, int(port_s)


def parse_controller(text: str | None) -> tuple[str, int | None] | None:
    """``--egm-controller`` value ``"IP"`` or ``"IP:PORT"`` (``"[IPv6]:PORT"``) -> ``(ip, port)``
    with ``port`` None when not given; None stays None.

    Raises:
        EgmAddressError: not an IP address, or a port that is not an integer in 1..65535.
    """
    if text is None:
        return None
    text = str(text).strip()
    host, port = text, None
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        if rest:
            port = rest.removeprefix(":")
    elif text.count(":") == 1:
        host, port = text.split(":")
    try:
        ip = str(ipaddress.ip_address(host))
        if port is not None and not (port.isdigit() and 1 <= int(port) <= 65535):
            raise ValueError
    except ValueError:
        raise EgmAddressError(
            f"--egm-controller: {text!r} is not IP or IP:PORT (e.g. 192.168.125.1, "
            "192.168.125.1:6510, [::1]:6510)"
        ) from None
    return ip, None if port is None else int(port)
