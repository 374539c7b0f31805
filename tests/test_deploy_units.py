"""examples/systemd/: the units pass ``systemd-analyze verify`` and every option their
ExecStart gives exists in the program (the real command line, parsed by the real CLI)."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
UNITS = ROOT / "examples/systemd"
BIN = Path(sys.executable).parent


def exec_start(unit: Path) -> list[str]:
    """ExecStart's argument vector (continuation lines joined, a ``sh -c '...'`` unwrapped,
    systemd's ``%%`` unescaped)."""
    text = unit.read_text().replace("\\\n", " ")
    line = re.search(r"^ExecStart=(.*)$", text, re.M).group(1).replace("%%", "%")
    argv = shlex.split(line)
    if argv[:2] == ["/bin/sh", "-c"]:  # the shell's $(date ...) becomes one word
        argv = shlex.split(re.sub(r"\$\([^)]*\)", "NOW", argv[2].removeprefix("exec ")))
    return argv


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="needs systemd-analyze")
@pytest.mark.parametrize("name", ["thinkfast-run.service", "thinkfast-detect.service"])
def test_units_verify(name, tmp_path):
    unit = tmp_path / name
    unit.write_text((UNITS / name).read_text().replace("/opt/thinkfast/.venv/bin/", f"{BIN}/"))
    out = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert out.returncode == 0 and not out.stderr.strip(), out.stderr


def test_the_daemon_unit_command_line_parses(small_tree_015, tmp_path):
    argv = exec_start(UNITS / "thinkfast-run.service")
    assert Path(argv[0]).name == "thinkfast-run"
    assert {"--reply-process", "--cpu", "--fifo", "--record"} <= set(argv)
    config = tmp_path / "RUN.toml"
    config.write_text("")
    swap = {"--tree": str(small_tree_015), "--config": str(config),
            "--record": str(tmp_path / "r.h5")}  # fmt: skip
    args = [swap.get(argv[i - 1], a) for i, a in enumerate(argv) if i > 0]
    out = subprocess.run([str(BIN / "thinkfast-run"), *args, "--check-config", str(config)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "KillSignal=SIGINT" in (UNITS / "thinkfast-run.service").read_text()


def test_the_detector_unit_command_line_parses(tmp_path):
    argv = exec_start(UNITS / "thinkfast-detect.service")
    assert Path(argv[0]).name == "thinkfast-detect"
    args = [str(ROOT / "examples/DETECT.toml") if argv[i - 1] == "--config" else a
            for i, a in enumerate(argv) if i > 0]  # fmt: skip
    out = subprocess.run([str(BIN / "thinkfast-detect"), *args, "--print-config"],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr


@pytest.mark.parametrize(
    "name, node", [("thinkfast-run.service", "daemon"), ("thinkfast-detect.service", "camera-base")]
)
def test_the_units_run_the_secured_cells_nodes(name, node):
    """Each unit's zenoh session is the secured cell's node of examples/zenoh/secured/ (the
    daemon refuses a plain listener on the network: docs/SECURITY.md)."""
    from thinkfast.contract.zenoh_session import session_config, session_security

    argv = exec_start(UNITS / name)
    path = Path(argv[argv.index("--zenoh-config") + 1])
    assert path.name == f"{node}.json5"
    assert not {"--zenoh-listen", "--zenoh-connect", "--insecure-zenoh"} & set(argv)
    example = ROOT / "examples" / "zenoh" / "secured" / path.name
    assert session_security(session_config(config_file=example)).mode == "tls"
