"""The controller links the daemon may open, by name (``thinkfast-run --link``).

A link is one module with a factory ``open(spec, reply) -> ControllerLink``
(:class:`thinkfast.control.link.ControllerLink`) and one line here, or one :func:`register`
call from outside the package (a test's in-memory controller, a lab's own interface).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import NamedTuple

from thinkfast.control.link import ControllerLink, ReplyFn
from thinkfast.errors import ConfigError


class LinkSpec(NamedTuple):
    """Where and how a link talks to its controller (the daemon's endpoints).

    Attributes:
        bind: ``HOST:PORT`` the link listens on (EGM: the UDP socket; port 0: any free one).
        controller: the one controller to serve (``IP`` or ``IP:PORT``), None: the first.
        handover: a silent controller [s] after which another may take over.
        dt: the controller's cycle [s] (a reply later than this is late).
    """

    bind: str = "0.0.0.0:6510"
    controller: str | None = None
    handover: float = 1.0
    dt: float = 0.004


LinkFactory = Callable[[LinkSpec, ReplyFn], ControllerLink]
# name -> "module:function" (imported when opened) or a factory registered at run time
LINKS: dict[str, str | LinkFactory] = {"egm": "thinkfast.link.egm:open_egm"}


def register(name: str, factory: LinkFactory) -> None:
    """Make ``factory`` the link called ``name`` (replacing one of that name)."""
    LINKS[name] = factory


def names() -> list[str]:
    """The links that may be opened."""
    return sorted(LINKS)


def open_link(name: str, spec: LinkSpec, reply: ReplyFn) -> ControllerLink:
    """Open the link ``name`` answering each feedback with ``reply(feedback, before)``.

    Raises:
        ConfigError: no link of that name (the message lists the links there are).
    """
    entry = LINKS.get(name)
    if entry is None:
        raise ConfigError(
            "--link", None, f"no controller link {name!r}; links: {', '.join(names())}"
        )
    if isinstance(entry, str):
        module, _, func = entry.partition(":")
        entry = getattr(importlib.import_module(module), func)
    return entry(spec, reply)
