"""Config tooling: --print-config / --check-config, example configs, --version, upper bounds."""

from __future__ import annotations

import dataclasses
import importlib
import tomllib
from dataclasses import dataclass

import pytest

from tests.conftest import DEFAULT_CONFIG, ROOT, assert_one_line_error, run_cli
from thinkfast import __version__
from thinkfast.cli_util import asks_version, run_app
from thinkfast.compile.config import load_compile_config
from thinkfast.config import from_dict, spec, to_dict, to_toml
from thinkfast.control.config import RunConfig, load_run_config, run_config_toml
from thinkfast.errors import ConfigError
from thinkfast.perception.config import DetectConfig, detect_config_toml, load_detect_config

EXAMPLES = ROOT / "examples"
COMMANDS = {
    "thinkfast-compile": "thinkfast.compile.cli",
    "thinkfast-run": "thinkfast.daemon.cli",
    "thinkfast-sim": "thinkfast.sweep.cli",
    "thinkfast-detect": "thinkfast.perception.cli",
    "thinkfast-zed": "thinkfast.perception.zed_cli",
    "thinkfast-calib": "thinkfast.calib.cli",  # skipped until that command exists
}


@dataclass(frozen=True)
class Item:
    """One item."""

    name: str = spec("a", doc="item name")
    size: tuple[float, ...] = spec((1.0,), unit="m", lo=0.0)


@dataclass(frozen=True)
class Top:
    """Top."""

    scale: float = spec(1.5, unit="1", doc="a scale", lo=0.0, hi=2.0)
    flag: bool = spec(False, doc="a flag")
    items: tuple[Item, ...] = spec((Item(), Item("b", (2.0, 3.0))))
    note: str | None = spec(None, doc="optional")


def _run(module: str, prog: str, *argv: str) -> int:
    return run_app(importlib.import_module(module).app, prog, list(argv))


def _keys(table: dict, prefix: str = "") -> set[str]:
    """Dotted keys of every leaf of a TOML table."""
    out = set()
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else k
        out |= _keys(v, key) if isinstance(v, dict) else {key}
    return out


def test_print_config_is_read_back_by_config_as_the_defaults(tmp_path, capsys):
    assert _run("thinkfast.daemon.cli", "thinkfast-run", "--print-config") == 0
    text = capsys.readouterr().out
    path = tmp_path / "run.toml"
    path.write_text(text)
    assert load_run_config(path) == RunConfig()
    # every key of the config is written (not just the ones a table overrides)
    assert _keys(tomllib.loads(text)) == _keys(to_dict(RunConfig()))
    assert "ASSUMED" in text and "controller_lag = 0.04  # s, >= 0, <= 0.5" in text


def test_print_config_writes_a_changed_config_exactly(tmp_path):
    cfg = RunConfig()
    cfg = dataclasses.replace(
        cfg,
        execution=dataclasses.replace(cfg.execution, controller_lag=0.07),
        camera=dataclasses.replace(cfg.camera, rpy=(0.0, 0.1, -0.25)),
        robot='odd "name"\\path.toml',
    )
    path = tmp_path / "run.toml"
    path.write_text(run_config_toml(cfg))
    assert load_run_config(path) == cfg


def test_check_config_prints_ok_for_a_valid_file(tmp_path, capsys):
    path = tmp_path / "run.toml"
    path.write_text("[execution]\ncontroller_lag = 0.06\n")
    assert _run("thinkfast.daemon.cli", "thinkfast-run", "--check-config", str(path)) == 0
    assert capsys.readouterr().out.strip() == f"{path}: OK"


@pytest.mark.parametrize(
    "body, key, problem",
    [
        (
            "[camera]\nrpy = [0, 0, 90]\n",
            "camera.rpy[2]",
            "got 90 (degrees? 90 deg = 1.571 rad)",
        ),
        ("[execution]\ncontroller_lag = 40\n", "execution.controller_lag", "must be <= 0.5 s"),
        ("[safety]\ntracking_lag = 200\n", "safety.tracking_lag", "must be <= 2 s"),
        ("[throw]\nmax_tau = 0\n", "throw.max_tau", "must be > 0 s"),
        ("[execution]\ncontroler_lag = 0.04\n", "execution.controler_lag", "unknown key"),
        ('robot = "nowhere/robot.toml"\n', "nowhere/robot.toml", "not found"),
    ],
)
def test_check_config_refuses_with_one_line_naming_the_key(tmp_path, body, key, problem):
    path = tmp_path / "run.toml"
    path.write_text(body)
    proc = run_cli("thinkfast-run", "--check-config", str(path))
    assert proc.returncode == 1 and proc.stdout == ""
    assert_one_line_error(proc, "thinkfast-run: error:", key, problem)


def test_run_without_tree_is_a_usage_error_naming_tree():
    proc = run_cli("thinkfast-run", "--planner", "naive")
    assert proc.returncode == 2
    assert_one_line_error(proc, "--tree")


def test_detect_print_config_is_read_back_as_the_defaults(tmp_path, capsys):
    assert _run("thinkfast.perception.cli", "thinkfast-detect", "--print-config") == 0
    text = capsys.readouterr().out
    path = tmp_path / "detect.toml"
    path.write_text(text)
    assert load_detect_config(path) == DetectConfig()
    assert _keys(tomllib.loads(text)) == _keys(to_dict(DetectConfig()))


def test_degrees_for_the_detector_camera_are_refused(tmp_path):
    path = tmp_path / "detect.toml"
    path.write_text("[camera]\nrpy = [0, 0, 90]\n")
    with pytest.raises(ConfigError) as err:
        load_detect_config(path)
    assert err.value.key == "camera.rpy[2]"


def test_example_configs_load_with_the_real_loaders_and_are_current():
    run = EXAMPLES / "RUN.toml"
    detect = EXAMPLES / "DETECT.toml"
    assert load_run_config(run) == RunConfig()
    assert load_detect_config(detect) == DetectConfig()
    # generated files: regenerate with `thinkfast-run --print-config > examples/RUN.toml` (and
    # `thinkfast-detect --print-config > examples/DETECT.toml`) when a config class changes
    assert run.read_text() == run_config_toml(), "examples/RUN.toml is stale"
    assert detect.read_text() == detect_config_toml(), "examples/DETECT.toml is stale"
    assert load_compile_config(DEFAULT_CONFIG).config.tree.max_depth >= 1


def test_to_toml_writes_arrays_of_tables_and_unset_keys():
    text = to_toml(Top(), "title line")
    data = tomllib.loads(text)
    assert text.startswith("# title line\n")
    assert "scale = 1.5  # 1, >= 0, <= 2" in text and "# note = (unset)" in text
    assert data["items"] == [{"name": "a", "size": [1.0]}, {"name": "b", "size": [2.0, 3.0]}]
    back = from_dict(Top, {**data, "items": data["items"]}, "t.toml")
    assert back.scale == 1.5 and back.flag is False and back.note is None


@pytest.mark.parametrize("prog", list(COMMANDS))
def test_version_on_every_command(prog, capsys):
    try:
        importlib.import_module(COMMANDS[prog])
    except ModuleNotFoundError:
        pytest.skip(f"{prog} is not part of this tree")
    for argv in (["--version"], ["--help", "--version"], ["sub", "--version", "x"]):
        assert _run(COMMANDS[prog], prog, *argv) == 0
        assert capsys.readouterr().out == f"{prog} thinkfast {__version__}\n"


def test_version_as_a_real_process():
    proc = run_cli("thinkfast-compile", "--version")
    assert proc.returncode == 0 and proc.stdout == f"thinkfast-compile thinkfast {__version__}\n"


def test_version_after_double_dash_is_an_argument():
    assert asks_version(["run", "--version"]) and not asks_version(["--", "--version"])


@pytest.mark.parametrize(
    "body, key, needle",
    [
        ("[camera]\nrpy = [0, 5, 0]\n", "camera.rpy[1]", "(degrees? 5 deg = 0.08727 rad)"),
        ("[camera]\nxyz = [460, 0, 300]\n", "camera.xyz[0]", "(millimetres? 460 mm = 0.46 m)"),
        (
            "[execution]\ncontroller_lag = 0.05\n[safety]\ntracking_lag = 0.03\n",
            "safety.tracking_lag",
            "below execution.controller_lag (0.05 s)",
        ),
        ("[execution]\ntracking_lag = 0.3\n", "execution.tracking_lag", "is a key of [safety]"),
        ("controller_lag = 0.03\n", "controller_lag", "is a key of [execution]"),
    ],
)
def test_unit_slips_and_cross_key_mistakes_name_the_key_and_the_fix(tmp_path, body, key, needle):
    from thinkfast.control.config import load_run_config

    path = tmp_path / "run.toml"
    path.write_text(body)
    with pytest.raises(ConfigError) as err:
        load_run_config(path)
    assert err.value.key == key
    assert needle in str(err.value) and str(path) in str(err.value)


def test_a_missing_camera_file_names_the_config_and_the_key(tmp_path):
    from thinkfast.control.config import load_run_config

    path = tmp_path / "run.toml"
    path.write_text('camera_file = "cam.toml"\n')
    with pytest.raises(ConfigError) as err:
        load_run_config(path)
    assert err.value.source == str(path) and err.value.key == "camera_file"
    assert str(tmp_path / "cam.toml") in str(err.value) and "file not found" in str(err.value)
