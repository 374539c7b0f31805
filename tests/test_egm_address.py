"""EGM addresses from the command line: what is taken, and errors that show the expected form."""

import pytest

from thinkfast.link.egm_address import EgmAddressError, parse_controller, parse_hostport


@pytest.mark.parametrize(
    "text, expected",
    [
        ("0.0.0.0:6510", ("0.0.0.0", 6510)),
        ("127.0.0.1:0", ("127.0.0.1", 0)),
        (" localhost:6511 ", ("localhost", 6511)),
        ("[::1]:6512", ("::1", 6512)),
    ],
)
def test_parse_hostport_accepts_host_colon_port(text, expected):
    assert parse_hostport(text) == expected


@pytest.mark.parametrize("text", ["6510", ":6510", "host:", "host:abc", "host:70000", "h:-1", ""])
def test_parse_hostport_refuses_with_an_example_in_the_message(text):
    with pytest.raises(EgmAddressError, match="HOST:PORT"):
        parse_hostport(text)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("192.168.125.1", ("192.168.125.1", None)),
        ("192.168.125.1:6511", ("192.168.125.1", 6511)),
        ("[::1]:6510", ("::1", 6510)),
        ("::1", ("::1", None)),
        (None, None),
    ],
)
def test_controller_is_an_ip_with_an_optional_port(text, expected):
    assert parse_controller(text) == expected


@pytest.mark.parametrize("bad", ["robot", "1.2.3.4:0", "1.2.3.4:x", "1.2.3.4:70000", "1.2.3"])
def test_a_controller_that_is_not_an_ip_with_a_port_is_refused_by_name(bad):
    with pytest.raises(EgmAddressError, match="--egm-controller"):
        parse_controller(bad)
