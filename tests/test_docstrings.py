"""Module docstrings stay short and the package's files carry no issue numbers or dates: the
specification lives in docs/, the code says what a module is and points there."""

from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "thinkfast"
MAX_LINES = 25
TRACKER = re.compile(r"issue [0-9]+|20[0-9]{2}-[0-9]{2}-[0-9]{2}")


def modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_every_module_has_a_docstring_of_at_most_25_lines():
    """Every module under thinkfast/ has a module docstring, and none is longer than 25 lines."""
    assert len(modules()) > 50  # the test reads the package
    offenders = []
    for path in modules():
        doc = ast.get_docstring(ast.parse(path.read_text()), clean=False)
        lines = len(doc.splitlines()) if doc else 0
        if not doc or lines > MAX_LINES:
            offenders.append(f"{path.relative_to(PACKAGE.parent)}: {lines} lines")
    assert not offenders, f"module docstrings missing or over {MAX_LINES} lines: {offenders}"


def test_no_issue_numbers_or_dates_in_the_package():
    """No file under thinkfast/ contains "issue N" or a date YYYY-MM-DD."""
    files = [p for p in sorted(PACKAGE.rglob("*")) if p.is_file() and p.suffix != ".pyc"]
    assert files
    hits = []
    for path in files:
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if TRACKER.search(line):
                hits.append(f"{path.relative_to(PACKAGE.parent)}:{number}: {line.strip()}")
    assert not hits, f"issue numbers or dates in the package: {hits}"


def test_the_patterns_catch_what_they_should():
    """The checks above would see an issue number, a date and an overlong docstring."""
    assert TRACKER.search("see issue 42") and TRACKER.search("on 2026-12-03")
    assert not TRACKER.search("issues of 2026")
    doc = ast.get_docstring(ast.parse('"""' + "line\n" * 30 + '"""'), clean=False)
    assert len(doc.splitlines()) > MAX_LINES
