"""Digest authentication of the fake RWS controller (RFC 7616, MD5, qop=auth): the answer a
client computes is accepted, and only that one (the fake on real HTTP: tests/test_cell.py)."""

from __future__ import annotations

import hashlib

import pytest

from thinkfast.sim.rws_http import REALM, DigestAuth, digest_fields


def _answer(auth_header: str, user: str, password: str, method: str, uri: str) -> str:
    """What a client sends back to a challenge (computed here, independently of the server)."""
    f = digest_fields(auth_header.removeprefix("Digest "))

    def h(x):
        return hashlib.md5(x.encode()).hexdigest()

    ha1, ha2 = h(f"{user}:{f['realm']}:{password}"), h(f"{method}:{uri}")
    response = h(f"{ha1}:{f['nonce']}:00000001:abcdef:auth:{ha2}")
    return (
        f'Digest username="{user}", realm="{f["realm"]}", nonce="{f["nonce"]}", uri="{uri}", '
        f'response="{response}", qop=auth, nc=00000001, cnonce="abcdef", algorithm=MD5'
    )


def test_quoted_values_may_hold_commas_and_keys_are_lower_case():
    fields = digest_fields('Realm="a, b", nonce="x", qop=auth, nc=00000001')
    assert fields == {"realm": "a, b", "nonce": "x", "qop": "auth", "nc": "00000001"}
    assert digest_fields('a="unterminated') == {"a": "unterminated"}


def test_a_challenge_names_the_realm_and_a_fresh_nonce():
    auth = DigestAuth("Default User", "robotics")
    a, b = digest_fields(auth.challenge()[7:]), digest_fields(auth.challenge(stale=True)[7:])
    assert a["realm"] == REALM and a["qop"] == "auth" and a["nonce"] != b["nonce"]
    assert b["stale"] == "true"


def test_the_right_answer_is_accepted():
    auth = DigestAuth("Default User", "robotics")
    header = _answer(auth.challenge(), "Default User", "robotics", "GET", "/rw/panel/opmode?json=1")
    assert auth.authorised("GET", header)


@pytest.mark.parametrize(
    "user, password, method, nonce",
    [
        ("Default User", "wrong", "GET", None),
        ("Someone", "robotics", "GET", None),
        ("Default User", "robotics", "POST", None),  # answered for GET, sent as POST
        ("Default User", "robotics", "GET", "0" * 32),  # a nonce the server never gave
    ],
)
def test_any_other_answer_is_refused(user, password, method, nonce):
    auth = DigestAuth("Default User", "robotics")
    challenge = auth.challenge()
    if nonce is not None:
        challenge = challenge.replace(digest_fields(challenge[7:])["nonce"], nonce)
    header = _answer(challenge, user, password, "GET", "/rw/panel/opmode?json=1")
    assert not auth.authorised(method, header)
    assert not auth.authorised("GET", None) and not auth.authorised("GET", "Basic abc")
