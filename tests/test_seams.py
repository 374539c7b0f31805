"""The seams the codebase is cut along hold: outside the control core's package nothing reads
the executor (the core returns what happened and answers queries), and the daemon's modules
reach the controller through a link, never through EGM's server directly."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "thinkfast"
EXECUTOR_NAMES = {"ex", "executor"}


def _executor_reads(tree: ast.AST) -> list[tuple[int, str]]:
    """``ex.x``, ``executor.x``, ``a.executor.x`` and any ``a.ex``: reads of the executor."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        inner = node.value
        named = (isinstance(inner, ast.Name) and inner.id in EXECUTOR_NAMES) or (
            isinstance(inner, ast.Attribute) and inner.attr in EXECUTOR_NAMES
        )
        if named or node.attr == "ex":
            found.append((node.lineno, ast.unparse(node)))
    return found


def test_nothing_outside_control_reads_the_executor():
    """Every module outside thinkfast/control/ is free of executor attribute reads: the
    daemon, the simulators and the views use the core's outcome and queries."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if "control" in path.relative_to(PACKAGE).parts[:1]:
            continue
        for line, text in _executor_reads(ast.parse(path.read_text())):
            offenders.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {text}")
    assert not offenders, "\n".join(offenders)


def test_the_executor_check_sees_a_read():
    """The check above is not blind: each form of a read is found."""
    src = "a = ex.mode\nb = self.executor.belief\nc = control.ex\nd = executor.node\n"
    assert [t for _, t in _executor_reads(ast.parse(src))] == [
        "ex.mode", "self.executor.belief", "control.ex", "executor.node",
    ]  # fmt: skip
    assert _executor_reads(ast.parse("plan_key(self.executor, 1)\nx = core.state().mode")) == []


def test_the_daemon_opens_its_controller_through_the_link_registry():
    """No module of the daemon builds an EGM server itself: the link registry opens it (the
    reply process's EGM link included)."""
    offenders = []
    for path in sorted((PACKAGE / "daemon").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and ast.unparse(node.func).endswith("EgmServer"):
                offenders.append(f"{path.name}:{node.lineno}")
    assert not offenders, offenders
