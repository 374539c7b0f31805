"""The docs name only status keys that exist: every `status.KEY.SUB` in docs/*.md and the
README resolves in docs/schemas/status.schema.json, whose EGM counters are the daemon's."""

from __future__ import annotations

import dataclasses
import functools
import json
import re
from pathlib import Path

from thinkfast.link.egm_server import EgmCounters

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs/schemas/status.schema.json").read_text())
STATUS_KEY = re.compile(r"`status\.([a-z_]+(?:\.[a-z_]+)*)`")


def resolve(schema: dict, path: list[str]) -> bool:
    """Whether the dotted ``path`` is a named property of ``schema`` (nested objects)."""
    node = schema
    for name in path:
        props = node.get("properties", {})
        if name not in props:
            return False
        node = props[name]
    return True


def doc_status_keys() -> list[tuple[str, str]]:
    files = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
    return [(f.name, m.group(1)) for f in files for m in STATUS_KEY.finditer(f.read_text())]


def test_every_status_key_the_docs_name_is_in_the_schema():
    found = doc_status_keys()
    assert len(found) >= 8  # CELL.md names them: the test reads something
    missing = [(f, k) for f, k in found if not resolve(SCHEMA, k.split("."))]
    assert not missing, f"status keys named in the docs but not in the schema: {missing}"


def test_a_missing_key_is_caught():
    assert not resolve(SCHEMA, ["egm", "missed"])
    assert resolve(SCHEMA, ["egm", "superseded"]) and resolve(SCHEMA, ["controller", "standby"])


def test_the_schemas_egm_counters_are_the_daemons():
    named = set(SCHEMA["properties"]["egm"]["properties"])
    daemon = {f.name for f in dataclasses.fields(EgmCounters)} | {"repeated", "resyncs"}
    assert named == daemon


# --- docs/CELL.md "Troubleshooting": the log lines it quotes are the daemon's ---------------

LEVEL_LINE = re.compile(r"^(?:(?:DEBUG|INFO|WARNING|ERROR) )?(.+)$")
EVENT_LINE = re.compile(r"^(?:(?:INFO|WARNING|ERROR) )?([a-z_]+)(?: (\{.*\}))?$")
PERCENT = re.compile(r"%[-#0 +]*\d*(?:\.\d+)?[sdirfgex]")


def troubleshooting_quotes() -> list[str]:
    """The backticked spans of the first column of docs/CELL.md section 9's table (what a user
    sees), but status keys (checked above), command lines and the two messages checked where
    they are made: the config loader's (below) and ``thinkfast-calib dynamics``' verdict
    (tests/test_calib.py, ``max_acceleration[0] = 12.00: not measured (commanded at most``)."""
    text = (ROOT / "docs/CELL.md").read_text()
    section = text.split("## 9. Troubleshooting", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and "---" not in ln]
    spans = [s for row in rows[1:] for s in re.findall(r"`([^`]+)`", row.split(" | ")[0])]
    skip = ("status.", "camera.rpy[", "max_acceleration[")
    return [s for s in spans if not s.startswith(skip) and not re.match(r"thinkfast-\w+ ", s)]


@functools.cache
def code_strings() -> tuple[set[str], list[list[str | None]]]:
    """Every string literal of the package, and every string it could format (a literal with
    %-placeholders or an f-string) as pieces: text, and None where a value goes."""
    import ast

    literals: set[str] = set()
    formats: list[list[str | None]] = []
    for path in (ROOT / "thinkfast").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                literals.add(node.value)
                pieces: list[str | None] = []
                for k, part in enumerate(PERCENT.split(node.value)):
                    pieces += ([None] if k else []) + [part]
                formats.append(pieces)
            elif isinstance(node, ast.JoinedStr):
                formats.append(
                    [v.value if isinstance(v, ast.Constant) else None for v in node.values]
                )
    return literals, formats


def quote_matches(quote: str, pieces: list[str | None]) -> bool:
    """Whether ``quote`` (a doc's line, ``...`` where it leaves text out) reads as the start of
    what ``pieces`` format (None: any value)."""
    doc: list[str | None] = []
    for k, part in enumerate(quote.split("...")):
        doc += ([None] if k else []) + list(part)
    code: list[str | None] = [c for p in pieces for c in ([None] if p is None else list(p))]

    @functools.cache
    def match(i: int, j: int) -> bool:
        if i == len(doc):  # the doc may quote the start of a longer message, up to its text
            return j == len(code) or code[j] is not None  # (not into a value)
        if doc[i] is None and (match(i + 1, j) or (j < len(code) and match(i, j + 1))):
            return True
        if j == len(code):
            return False
        if code[j] is None:
            return match(i, j + 1) or match(i + 1, j)
        return doc[i] == code[j] and match(i + 1, j + 1)

    return match(0, 0)


def unmatched_quotes(quotes: list[str]) -> list[str]:
    """The quotes that are neither an event the package logs (its name, detail keys and
    detail phrases are the package's literals) nor the start of a message it formats."""
    literals, formats = code_strings()
    bad = []
    for quote in quotes:
        event = EVENT_LINE.match(quote)
        if event:
            detail = event.group(2) or ""
            keys = re.findall(r'"([a-z_]+)": ', detail)
            phrases = [v for v in re.findall(r': "([^"]+)"', detail) if v.count(" ") >= 2]
            if not all(w in literals for w in [event.group(1), *keys, *phrases]):
                bad.append(quote)
            continue
        message = LEVEL_LINE.match(quote).group(1)
        first = message.split("...")[0][:12]
        candidates = [p for p in formats if p[0] and p[0][:12] == first]
        if not any(quote_matches(message, p) for p in candidates):
            bad.append(quote)
    return bad


def test_every_log_line_the_troubleshooting_table_quotes_is_one_the_package_writes():
    quotes = troubleshooting_quotes()
    assert len(quotes) >= 12  # the table quotes them: the test reads something
    assert not unmatched_quotes(quotes), unmatched_quotes(quotes)


def test_a_log_line_the_package_never_writes_is_caught():
    made_up = [
        'INFO egm_missed {"peer": "192.168.125.1:..."}',  # no such event
        'INFO brake {"reason": "signal", "brake_cause_text": "..."}',  # no such key
        "WARNING detection rejected (stale: ...)",  # not the message's words
        "ERROR the way home collides (...): braking",  # not how it ends
    ]
    assert unmatched_quotes(made_up) == made_up
    assert not unmatched_quotes(["WARNING detection dropped (stale: stamp 1.5), 3 so far"])


def test_the_quoted_unit_slip_is_the_config_loaders_message(tmp_path):
    """The table's ``--check-config`` line is what the loader says for degrees in rpy."""
    from thinkfast.control.config import load_run_config
    from thinkfast.errors import ConfigError

    text = (ROOT / "docs/CELL.md").read_text()
    quote = re.search(r"refuses `(camera\.rpy\[1\]: [^`]+)`", text).group(1)
    path = tmp_path / "RUN.toml"
    path.write_text("[camera]\nrpy = [0, 5, 0]\n")
    try:
        load_run_config(path)
    except ConfigError as err:
        message = str(err)
    else:
        raise AssertionError("degrees in rpy were taken")
    start = message.index("camera.rpy[1]")
    assert quote_matches(quote, [message[start:]]), (quote, message)
