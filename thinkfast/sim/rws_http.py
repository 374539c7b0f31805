"""HTTP/1.1 with digest authentication for the fake RWS controller (sim/rws_server.py).

What ``abb_robot_client.rws.RWS`` (0.4.0) expects of the transport: digest authentication
(RFC 7616, MD5, ``qop=auth``; the client answers the first 401 challenge and then sends its
``Authorization`` header with every request, :class:`DigestAuth`), keep-alive connections, JSON
answers (:func:`make_handler`). The resources and the simulated program are the controller's.
"""

from __future__ import annotations

import hashlib
import json
import secrets
import threading
from http.server import BaseHTTPRequestHandler
from urllib.parse import parse_qs, urlsplit

REALM = "validusers@robapi.abb"  # the realm RobotWare 6 announces (ASSUMED, from public traces)


class DigestAuth:
    """The one account the fake accepts, and the nonces it handed out.

    Args:
        username, password: the account (RobotWare 6's default user by default in the fake).
    """

    def __init__(self, username: str, password: str):
        self.username, self.password = username, password
        self.lock = threading.Lock()
        self._nonces: set[str] = set()

    def challenge(self, stale: bool = False) -> str:
        """A fresh ``WWW-Authenticate: Digest ...`` header value."""
        nonce = secrets.token_hex(16)
        with self.lock:
            self._nonces.add(nonce)
        extra = ", stale=true" if stale else ""
        return f'Digest realm="{REALM}", nonce="{nonce}", qop="auth", algorithm=MD5{extra}'

    def authorised(self, method: str, header: str | None) -> bool:
        """True when ``header`` is a digest answer for our user, password and one of our nonces."""
        if not header or not header.lower().startswith("digest "):
            return False
        fields = digest_fields(header[7:])
        with self.lock:
            known = fields.get("nonce") in self._nonces
        if not known or fields.get("username") != self.username or fields.get("realm") != REALM:
            return False
        ha1 = md5_hex(f"{self.username}:{REALM}:{self.password}")
        ha2 = md5_hex(f"{method}:{fields.get('uri', '')}")
        if fields.get("qop") == "auth":
            parts = (ha1, fields["nonce"], fields.get("nc", ""), fields.get("cnonce", ""), "auth")
            expected = md5_hex(":".join((*parts, ha2)))
        else:
            expected = md5_hex(f"{ha1}:{fields['nonce']}:{ha2}")
        return secrets.compare_digest(expected, fields.get("response", ""))


def md5_hex(text: str) -> str:
    """MD5 of ``text`` (UTF-8) in hex, as digest authentication hashes its fields."""
    return hashlib.md5(text.encode()).hexdigest()


def digest_fields(text: str) -> dict[str, str]:
    """``a="x, y", b=z`` -> {a: "x, y", b: "z"} (quoted values may hold commas)."""
    out: dict[str, str] = {}
    i, n = 0, len(text)
    while i < n:
        while i < n and text[i] in " ,":
            i += 1
        eq = text.find("=", i)
        if eq < 0:
            break
        key = text[i:eq].strip().lower()
        i = eq + 1
        if i < n and text[i] == '"':
            end = text.find('"', i + 1)
            end = n if end < 0 else end
            out[key] = text[i + 1 : end]
            i = end + 1
        else:
            end = text.find(",", i)
            end = n if end < 0 else end
            out[key] = text[i:end].strip()
            i = end
    return out


def make_handler(ctrl) -> type[BaseHTTPRequestHandler]:
    """The request handler class of ``ctrl`` (a fake controller,
    :class:`~thinkfast.sim.rws_server.FakeRwsController`): digest authentication by
    ``ctrl.auth``, then ``ctrl.handle(method, path, query, form)``
    answered as JSON (or ``204`` without a body)."""

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"  # keep-alive, as the client's requests.Session expects
        disable_nagle_algorithm = True  # headers and body leave at once (no 40 ms ACK wait)

        def log_message(self, fmt: str, *args) -> None:
            pass

        def do_GET(self) -> None:  # noqa: N802 (stdlib name)
            self._serve("GET")

        def do_POST(self) -> None:  # noqa: N802
            self._serve("POST")

        def _serve(self, method: str) -> None:
            length = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(length).decode() if length else ""
            if not ctrl.auth.authorised(method, self.headers.get("Authorization")):
                self._send(401, b"401 Unauthorized", "text/plain", ctrl.auth.challenge())
                return
            parts = urlsplit(self.path)
            query = {k: v[0] for k, v in parse_qs(parts.query).items()}
            form = {k: v[0] for k, v in parse_qs(body).items()}
            status, payload = ctrl.handle(method, parts.path.strip("/"), query, form)
            if payload is None:
                self._send(status, b"", None)
            else:
                self._send(status, json.dumps(payload).encode(), "application/json")

        def _send(self, status: int, data: bytes, ctype: str | None, auth: str | None = None):
            self.send_response(status)
            if ctype is not None:
                self.send_header("Content-Type", ctype)
            if auth is not None:
                self.send_header("WWW-Authenticate", auth)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            if data:
                self.wfile.write(data)

    return Handler
