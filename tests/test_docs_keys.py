"""The docs name only status keys that exist: every `status.KEY.SUB` in docs/*.md and the
README resolves in docs/schemas/status.schema.json, whose EGM counters are the daemon's."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

from thinkfast.daemon.egm_server import EgmCounters

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
