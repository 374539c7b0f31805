"""The layers show in the folders and import downwards only (docs/ARCHITECTURE.md)."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "thinkfast"
BASE = {"errors", "config", "machine", "cli_util", "contract", "robot", "tree", "__version__"}
# what each package may import from thinkfast (besides itself)
ALLOWED = {
    "contract": {"errors", "config"},
    "robot": {"errors", "config", "contract"},
    "tree": {"errors", "config", "robot", "contract"},
    "estimate": BASE,
    "decide": BASE | {"estimate"},
    "control": BASE | {"estimate", "decide"},
    "record": BASE | {"control"},
    "link": BASE | {"control"},
    "reply": BASE | {"control", "link"},
    "view": BASE | {"estimate", "decide", "control", "record", "link"},
    "daemon": BASE | {"estimate", "decide", "control", "record", "link", "reply", "view"},
    "compile": BASE,
    "perception": BASE,
    "sim": BASE
    | {
        "estimate",
        "decide",
        "control",
        "record",
        "link",
        "reply",
        "view",
        "daemon",
        "compile",
        "perception",
    },
    "sweep": BASE | {"control", "compile", "sim"},
    "calib": BASE | {"estimate", "decide", "control", "record", "link", "view", "daemon", "sim"},
    "cell": {"errors", "cli_util", "contract"},  # contract: the secured cell's identities
}


def _imports(path: Path) -> set[str]:
    """Top-level thinkfast packages or modules that ``path`` imports."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("thinkfast"):
            parts = node.module.split(".")
            if len(parts) > 1:
                out.add(parts[1])
            else:
                out.update(a.name for a in node.names)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("thinkfast."):
                    out.add(a.name.split(".")[1])
    return out


def test_every_layer_imports_downwards_only():
    bad = []
    for pkg, allowed in ALLOWED.items():
        for path in sorted((ROOT / pkg).glob("*.py")):
            for dep in _imports(path) - allowed - {pkg}:
                bad.append(f"{path.relative_to(ROOT)} imports thinkfast.{dep}")
    assert not bad, "\n".join(bad)


def test_no_runtime_grab_bag_is_left():
    assert not (ROOT / "runtime").exists()
    for pkg in ALLOWED:
        assert (ROOT / pkg / "__init__.py").read_text(encoding="utf-8").strip(), pkg


def test_import_linter_contracts_hold():
    """pyproject.toml's [tool.importlinter] contracts (layers from calib/cell and sim down to
    contract; pure kernels free of sockets, zenoh, HDF5 and processes; no bench or test code in
    the package; what the record, the simulators, calib and cell stay free of; no import cycles
    between siblings: tests/test_import_cycles.py for single modules) hold."""
    import subprocess
    import sys

    exe = Path(sys.executable).parent / "lint-imports"
    proc = subprocess.run(
        [str(exe), "--no-cache"], capture_output=True, text=True, cwd=ROOT.parent, timeout=120
    )
    assert proc.returncode == 0, proc.stdout[-3000:]
    n = len(
        tomllib.loads((ROOT.parent / "pyproject.toml").read_text())["tool"]["importlinter"][
            "contracts"
        ]
    )
    assert f"{n} kept, 0 broken" in proc.stdout
