"""The controller kit (robots/irb1600/controller/) agrees with the daemon and with its doc.

One source of truth per value: the table of recommended RAPID arguments in
docs/EGM_CONTROLLER.md holds the EGM values, the daemon's code holds the port and the cycle,
robot.toml holds home. The RAPID module, the UDP device and the Motion configuration are read
with small parsers and compared with them, so that a change on one side only fails here.
"""

from __future__ import annotations

import inspect
import ipaddress
import math
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KIT = ROOT / "robots" / "irb1600" / "controller"
MOD = KIT / "ThinkfastEGM.mod"
SIO = KIT / "sys_cfg_udpuc.cfg"
MOC = KIT / "moc_ext_motion_thinkfast.cfg"
DOC = ROOT / "docs" / "EGM_CONTROLLER.md"
ROBOT_TOML = ROOT / "robots" / "irb1600" / "robot.toml"

# Row of the doc table ("argument" column) -> CONST of the module that carries its value.
DOC_ARG_TO_CONST = {
    r"\CommTimeout": "EGM_COMM_TIMEOUT",
    r"\SampleRate": "EGM_SAMPLE_RATE",
    r"\LpFilter": "EGM_LP_FILTER",
    r"\MaxSpeedDeviation": "EGM_MAX_SPEED_DEV",
    r"\J1..\J6": "EGM_CONV",
    r"\CondTime": "EGM_COND_TIME",
    "stop mode": "EGM_STOP_MODE",
    r"\RampOutTime": "EGM_RAMP_OUT_TIME",
    r"\RampInTime": "EGM_RAMP_IN_TIME",
    r"\PosCorrGain": "EGM_POS_CORR_GAIN",
}
JOINT_ARGS = tuple(rf"\J{i}" for i in range(1, 7))


# ----------------------------------------------------------------------------- parsers
def _strip_rapid_comments(text: str) -> str:
    """RAPID without its ``!`` comments (a ``!`` inside a string literal stays)."""
    return re.sub(r'("[^"]*")|!.*', lambda m: m.group(1) or "", text)


def rapid_consts(text: str) -> dict[str, tuple[str, str, str]]:
    """``CONST type NAME := value;`` -> {NAME: (type, value, comment on that line)}."""
    out = {}
    pat = re.compile(r"^\s*CONST\s+(\w+)\s+(\w+)\s*:=\s*(.+?);\s*(?:!\s*(.*))?$", re.MULTILINE)
    for m in pat.finditer(text):
        out[m.group(2)] = (m.group(1), m.group(3).strip(), (m.group(4) or "").strip())
    return out


def rapid_statements(text: str, instruction: str) -> list[str]:
    """Every statement (up to its ``;``, comments removed) that starts with ``instruction``."""
    code = _strip_rapid_comments(text)
    pat = re.compile(rf"(?<![\w\\]){instruction}\b([^;]*);", re.IGNORECASE)
    return [" ".join(m.group(0).split()) for m in pat.finditer(code)]


def rapid_named_args(stmt: str) -> dict[str, str | None]:
    r"""``\Arg:=value`` -> {``\Arg``: value}; a switch ``\Arg`` -> {``\Arg``: None}."""
    args: dict[str, str | None] = {}
    for m in re.finditer(r"(\\\w+)(?:\s*:=\s*([^\\;]+?))?\s*(?=\\|;|$)", stmt):
        args[m.group(1)] = None if m.group(2) is None else m.group(2).strip().rstrip(",").strip()
    return args


def rapid_positional_args(stmt: str) -> list[str]:
    """The comma-separated arguments before the first optional one (``\\...``)."""
    body = re.sub(r"^\s*\w+\s*", "", stmt.rstrip(";"))
    body = body.split("\\", 1)[0]
    return [a.strip() for a in body.split(",") if a.strip()]


def cfg_instances(text: str, section: str) -> list[dict[str, str]]:
    """Instances of one section of an ABB ``.cfg`` file: [{attribute: value}] (quotes removed).

    ``#`` lines are comments and section separators; ``\\`` at a line end continues it; an
    attribute without a value (a flag) maps to ``""``.
    """
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]
    joined = re.sub(r"\\\s*\n", " ", "\n".join(lines))
    out, inside = [], False
    for line in joined.splitlines():
        if re.match(r"^[A-Z_]+:\s*$", line):
            inside = line.strip() == f"{section}:"
            continue
        if inside and line.strip().startswith("-"):
            attrs = {}
            for m in re.finditer(r'-(\w+)(?:\s+("[^"]*"|[^\s-][^\s]*))?', line):
                attrs[m.group(1)] = (m.group(2) or "").strip('"')
            out.append(attrs)
    return out


def doc_table() -> dict[str, tuple[str, str, str]]:
    """Rows of the recommended-arguments table: {argument: (instructions, unit, start value)}."""
    rows = {}
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 5 or cells[0] in ("argument", "") or set(cells[0]) <= {"-"}:
            continue
        if cells[1] == "" or "EGM" not in cells[1]:
            continue
        rows[cells[0].replace("`", "")] = (cells[1], cells[2], cells[3].replace("`", ""))
    return rows


def rapid_value(text: str):
    """A RAPID literal as Python: number, ``[a, b]`` list of numbers, or the name itself."""
    text = text.strip()
    if text.startswith("["):
        return [float(x) for x in text.strip("[]").split(",")]
    try:
        return float(text)
    except ValueError:
        return text


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def mod_text() -> str:
    return MOD.read_text()


@pytest.fixture(scope="module")
def consts(mod_text):
    return rapid_consts(mod_text)


@pytest.fixture(scope="module")
def udpuc() -> dict[str, str]:
    devices = cfg_instances(SIO.read_text(), "COM_TRP")
    assert len(devices) == 1, devices
    return devices[0]


def _one(mod_text: str, instruction: str) -> str:
    stmts = rapid_statements(mod_text, instruction)
    assert len(stmts) == 1, f"{instruction}: expected one call, found {stmts}"
    return stmts[0]


# ----------------------------------------------------------------------------- parsers work
def test_parsers_on_small_samples():
    s = 'X a, b, "c" \\J1:=K \\J2 \\Rate:=4; ! \\Nope:=1\n'
    (stmt,) = rapid_statements(s, "X")
    assert rapid_positional_args(stmt) == ["a", "b", '"c"']
    assert rapid_named_args(stmt) == {r"\J1": "K", r"\J2": None, r"\Rate": "4"}
    assert rapid_consts("  CONST num A := 0.5; ! [s]\n") == {"A": ("num", "0.5", "[s]")}
    cfg = 'X:CFG_1.0:6:1::\n#\n# c\nCOM_TRP:\n\n  -Name "N" -Type "T" \\\n  -P 1 -F\n'
    assert cfg_instances(cfg, "COM_TRP") == [{"Name": "N", "Type": "T", "P": "1", "F": ""}]


# ----------------------------------------------------------------------------- doc <-> module
def test_doc_table_lists_exactly_the_kit_constants():
    assert set(doc_table()) == set(DOC_ARG_TO_CONST)


@pytest.mark.parametrize("arg", sorted(DOC_ARG_TO_CONST))
def test_const_matches_doc_recommendation(arg, consts):
    instructions, unit, start = doc_table()[arg]
    name = DOC_ARG_TO_CONST[arg]
    assert name in consts, f"{MOD.name}: no CONST {name} for {arg}"
    _, value, comment = consts[name]
    assert rapid_value(value) == rapid_value(start), f"{name} := {value}, doc says {start}"
    if unit:
        unit = unit.split(",")[0].strip()
        assert f"[{unit}]" in comment, f"{name}: unit comment [{unit}] missing ({comment!r})"


@pytest.mark.parametrize("arg", sorted(DOC_ARG_TO_CONST))
def test_instructions_use_the_const(arg, mod_text):
    """Every instruction the doc names for an argument passes the CONST (never a literal)."""
    instructions = re.findall(r"`(EGM\w+)`", doc_table()[arg][0])
    name = DOC_ARG_TO_CONST[arg]
    assert instructions, arg
    for instr in instructions:
        stmts = rapid_statements(mod_text, instr)
        assert stmts, f"{MOD.name}: no {instr}"
        for stmt in stmts:
            if arg == "stop mode":
                assert rapid_positional_args(stmt)[1] == name, stmt
            elif arg == r"\J1..\J6":
                named = rapid_named_args(stmt)
                assert all(named.get(j) == name for j in JOINT_ARGS), stmt
            else:
                assert rapid_named_args(stmt).get(arg) == name, f"{stmt}: {arg}:={name}"


def test_doc_sketch_agrees_with_the_table():
    """The RAPID sketch on the doc page uses the table's values (the page cannot drift)."""
    text = DOC.read_text()
    sketch = re.search(r"```\n(MODULE ThinkfastEGM.*?ENDMODULE)\n```", text, re.DOTALL)
    assert sketch, "docs/EGM_CONTROLLER.md: RAPID sketch not found"
    code = sketch.group(1)
    table = doc_table()
    local = {name: value for name, (_, value, _) in rapid_consts(code).items()}
    table_of = {j: table[r"\J1..\J6"][2] for j in JOINT_ARGS} | {
        arg: row[2] for arg, row in table.items()
    }
    seen = set()
    for instr in ("EGMSetupUC", "EGMActJoint", "EGMRunJoint"):
        for stmt in rapid_statements(code, instr):
            for arg, value in rapid_named_args(stmt).items():
                if arg in table_of and value is not None:
                    value = local.get(value, value)
                    assert rapid_value(value) == rapid_value(table_of[arg]), (stmt, arg)
                    seen.add(arg)
    (run,) = rapid_statements(code, "EGMRunJoint")
    assert rapid_positional_args(run)[1] == table["stop mode"][2]
    assert len(seen) == len(table) - 2 + len(JOINT_ARGS)  # all but "\J1..\J6" and stop mode
    assert "EGM_STOP_RAMP_DOWN" not in _strip_rapid_comments(code)


# ----------------------------------------------------------------------------- daemon <-> kit
def test_sample_rate_is_the_daemon_cycle(consts):
    from thinkfast.control.safety import SafetyConfig

    rate = float(consts["EGM_SAMPLE_RATE"][1])
    assert rate == pytest.approx(1000.0 * SafetyConfig().dt)
    assert rate % 4 == 0


def test_comm_timeout_outlasts_the_daemon_resync(consts):
    from thinkfast.control.safety import SafetyConfig

    assert float(consts["EGM_COMM_TIMEOUT"][1]) > SafetyConfig().resync_after


def test_position_and_speed_with_hold(consts, mod_text):
    """The daemon sends position and speedRef: PosCorrGain 1; stops hold where the arm is."""
    assert float(consts["EGM_POS_CORR_GAIN"][1]) == 1.0
    assert consts["EGM_STOP_MODE"][:2] == ("egmstopmode", "EGM_STOP_HOLD")
    assert "EGM_STOP_RAMP_DOWN" not in _strip_rapid_comments(mod_text)
    run = _one(mod_text, "EGMRunJoint")
    named = rapid_named_args(run)
    assert all(j in named and named[j] is None for j in JOINT_ARGS), run


def test_udp_port_is_the_daemon_default(udpuc):
    from thinkfast.daemon import cli
    from thinkfast.daemon.service import Endpoints
    from thinkfast.link.egm_address import parse_hostport

    option = inspect.signature(cli.run).parameters["egm_bind"].default
    assert option.default == cli.EGM_BIND_DEFAULT, "--egm-bind no longer uses EGM_BIND_DEFAULT"
    assert Endpoints().egm_bind == cli.EGM_BIND_DEFAULT
    _, port = parse_hostport(cli.EGM_BIND_DEFAULT)
    assert int(udpuc["RemotePortNumber"]) == port
    assert port > 0


def test_udp_device_matches_the_module(udpuc, consts, mod_text):
    setup = _one(mod_text, "EGMSetupUC")
    pos = rapid_positional_args(setup)
    assert pos[:2] == ["ROB_1", "egm_id"], setup
    assert pos[3] == "EGM_UC_DEVICE", setup
    assert consts["EGM_UC_DEVICE"][1] == f'"{udpuc["Name"]}"'
    assert udpuc["Type"] == "UDPUC"
    assert int(udpuc["LocalPortNumber"]) == 0
    ipaddress.IPv4Address(udpuc["RemoteAdress"])  # a placeholder, but a valid address
    named = rapid_named_args(setup)
    assert r"\Joint" in named and named[r"\Joint"] is None, setup


def test_motion_config_matches_the_module(consts, mod_text):
    (ext,) = cfg_instances(MOC.read_text(), "EXT_MOTION_DATA")
    pos = rapid_positional_args(_one(mod_text, "EGMSetupUC"))
    assert pos[2] == "EGM_EXT_CONFIG"
    assert consts["EGM_EXT_CONFIG"][1] == f'"{ext["name"]}"'
    assert ext["ext_motion_level"] == "0"  # raw: \LpFilter is the filtering
    assert float(ext["ext_motion_filter_bandwidth"]) == float(consts["EGM_LP_FILTER"][1])
    assert float(ext["ext_motion_Kp"]) > 0.0


def test_home_is_robot_toml_home(consts):
    home = tomllib.loads(ROBOT_TOML.read_text())["home"]
    typ, value, _ = consts["TF_HOME"]
    assert typ == "jointtarget"
    robax = [float(x) for x in re.match(r"\[\s*\[([^\]]*)\]", value).group(1).split(",")]
    assert robax == pytest.approx([math.degrees(q) for q in home], abs=1e-3)


def test_session_lost_is_handled(mod_text):
    code = _strip_rapid_comments(mod_text)
    handler = re.search(r"\bERROR\b(.*?)\bENDPROC\b", code, re.DOTALL)
    assert handler, "no error handler"
    body = handler.group(1)
    assert re.search(r"ERRNO\s*=\s*ERR_UDPUC_COMM", body)
    assert "ErrWrite" in body and "TPWrite" in body and "EGMReset" in body
    assert "RETRY" not in body and "TRYNEXT" not in body  # no automatic restart
    # the module's calls in order: id, setup, activate, run, reset at the end
    order = [code.find(f"{i} ") for i in ("EGMGetId", "EGMSetupUC", "EGMActJoint", "EGMRunJoint")]
    assert all(a < b for a, b in zip(order, order[1:], strict=False)) and order[0] >= 0
    assert code.find("EGMReset", order[-1]) > order[-1]


def test_doc_points_to_the_kit():
    text = DOC.read_text()
    links = re.findall(r"\]\((\.\./robots/irb1600/controller/[^)]*)\)", text)
    names = {Path(link).name for link in links}
    assert {MOD.name, SIO.name, MOC.name, "README.md"} <= names, names
    for link in links:
        assert (DOC.parent / link).resolve().exists(), link


# ----------------------------------------------------------------------------- the generator
ROBOT_TOMLS_WITH_KIT = sorted(
    p for p in ROOT.glob("robots/*/robot.toml") if (p.parent / "controller").is_dir()
)


def _kit_of(toml: Path) -> dict[str, str]:
    from thinkfast.compile.kit import controller_kit, robot_dir_label
    from thinkfast.robot.model import load_robot

    return controller_kit(load_robot(toml), robot_dir_label(toml))


def _compile_cli(capsys, *argv: str) -> tuple[int, str, str]:
    from thinkfast.cli_util import run_app
    from thinkfast.compile.cli import app

    code = run_app(app, "thinkfast-compile", list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _home_and_speed(mod: str) -> tuple[list[float], float]:
    consts = rapid_consts(mod)
    robax = re.match(r"\[\s*\[([^\]]*)\]", consts["TF_HOME"][1]).group(1)
    return [float(x) for x in robax.split(",")], float(consts["EGM_MAX_SPEED_DEV"][1])


def test_irb1600_kit_is_what_the_generator_writes():
    """robots/irb1600/controller is generated: an edit by hand fails here."""
    from thinkfast.compile.kit import KIT_FILES, kit_differences

    kit = _kit_of(ROBOT_TOML)
    assert tuple(kit) == KIT_FILES
    assert {MOD.name, SIO.name, MOC.name} <= set(kit)
    assert kit_differences(kit, KIT) == []
    for name, text in kit.items():
        head = "\n".join(text.splitlines()[:4])
        assert "GENERATED by `thinkfast-compile kit` from robots/irb1600/robot.toml" in head, name
        assert "do not edit by hand" in head, name


@pytest.mark.parametrize("toml", ROBOT_TOMLS_WITH_KIT, ids=lambda p: p.parent.name)
def test_every_robot_kit_is_up_to_date(toml, capsys):
    """`thinkfast-compile kit --check` on every robot folder that has a controller/."""
    code, out, err = _compile_cli(capsys, "kit", str(toml), "--check")
    assert code == 0, out + err
    assert "up to date" in out


def _toy_robot(tmp_path: Path, home_deg, vmax_deg) -> Path:
    """A copy of robots/irb1600 with another home and max_velocity (lower) in robot.toml."""
    import shutil

    folder = tmp_path / "toy_arm"
    shutil.copytree(
        ROOT / "robots" / "irb1600", folder, ignore=shutil.ignore_patterns("controller")
    )
    toml = folder / "robot.toml"
    text = toml.read_text()
    home = [math.radians(d) for d in home_deg]
    vmax = [math.radians(d) for d in vmax_deg]
    text, n_home = re.subn(r"(?m)^home = \[.*\]$", f"home = {home!r}", text)
    text, n_v = re.subn(r"(?m)^max_velocity = \[.*\]$", f"max_velocity = {vmax!r}", text)
    text = text.replace('name = "abb_irb1600_10_145"', 'name = "toy_arm_slow"')
    assert n_home == n_v == 1
    toml.write_text(text)
    return toml


# How every robot-specific line of the kit begins (header, comments, CONSTs, README).
ROBOT_LINES = (
    "<!-- GENERATED by `thinkfast-compile kit` from ",
    "! GENERATED by `thinkfast-compile kit` from ",
    "# GENERATED by `thinkfast-compile kit` from ",
    "! fastest positioning max_velocity of robot.toml (",
    "CONST num EGM_MAX_SPEED_DEV := ",
    "! joint ",  # v_max / a_max of the joints with the longest stop
    "! joints ",
    "! thinkfast's home (",
    "CONST jointtarget TF_HOME := ",
    "# Controller kit: the ",
    "thinkfast-compile kit ",
)
TOY_HOME_DEG = [10.0, -20.5, 30.25, -5.125, -40.0, 15.0]  # 4 decimals: exact in the kit
TOY_VMAX_DEG = [120.0, 99.7, 130.4, 200.0, 210.0, 250.0]  # fastest positioning: joint 3


def test_another_robot_gets_its_home_and_speed(tmp_path):
    from thinkfast.compile.kit import robot_dir_label
    from thinkfast.robot.model import load_robot

    toml = _toy_robot(tmp_path, TOY_HOME_DEG, TOY_VMAX_DEG)
    robot = load_robot(toml)
    kit = _kit_of(toml)
    home, speed = _home_and_speed(kit["ThinkfastEGM.mod"])
    assert home == pytest.approx([math.degrees(q) for q in robot.home], abs=1e-6)
    fastest = max(math.degrees(v) for v in robot.v_max[: robot.n_arm])
    assert speed == math.ceil(fastest) == 131  # rounded up: the cap holds no planned joint back
    assert all(speed >= math.degrees(v) for v in robot.v_max[: robot.n_arm])
    mod = kit["ThinkfastEGM.mod"]
    label = robot_dir_label(toml)
    assert f"{label}/robot.toml `home`" in mod and "toy_arm_slow" in mod
    assert "(130.4 deg/s, joint 3)" in mod
    assert "robots/irb1600" not in "".join(kit.values())
    # everything but the robot's own lines is the same text as the IRB 1600's kit
    base = _kit_of(ROBOT_TOML)
    for name, text in kit.items():
        mine, theirs = text.splitlines(), base[name].splitlines()
        assert len(mine) == len(theirs), name
        differ = [a for a, b in zip(mine, theirs, strict=True) if a != b]
        assert all(line.strip().startswith(ROBOT_LINES) for line in differ), (name, differ)
    # the same kit passes every check of this file that does not name the IRB 1600
    consts = rapid_consts(mod)
    assert set(consts) == set(rapid_consts(base["ThinkfastEGM.mod"]))
    for arg in set(DOC_ARG_TO_CONST) - {r"\MaxSpeedDeviation"}:
        assert (
            consts[DOC_ARG_TO_CONST[arg]][1]
            == rapid_consts(MOD.read_text())[DOC_ARG_TO_CONST[arg]][1]
        )


def test_home_rounding_and_float_noise():
    """Homes carry 4 decimals of a degree (RAPID num: 32-bit); a whole deg/s typed in rad/s
    is that integer, not one below it."""
    from thinkfast.compile.kit import format_joints, rapid_degrees

    assert rapid_degrees(0.0) == rapid_degrees(-0.0) == rapid_degrees(1e-9) == "0"
    assert rapid_degrees(math.radians(21.320992148)) == "21.3210"
    assert rapid_degrees(-0.05812399769004418) == "-3.3303"
    for q in (0.123456789, -1.987654321, 2.5e-5):
        assert abs(float(rapid_degrees(q)) - math.degrees(q)) <= 0.5e-4 + 1e-12
    assert format_joints([0]) == "joint 1"
    assert format_joints([1, 0]) == "joints 1-2"
    assert format_joints([0, 1, 3]) == "joints 1-2, 4"


def test_speed_cap_of_whole_degrees_in_rad_is_that_integer(tmp_path):
    from thinkfast.compile.kit import max_speed_deviation
    from thinkfast.robot.model import load_robot

    vmax = [175.0, 175.0, 175.0, 360.0, 360.0, 450.0]
    toml = _toy_robot(tmp_path, TOY_HOME_DEG, vmax)
    text = toml.read_text()  # the rad/s value a degree conversion may give, just below 175
    slow = math.nextafter(math.radians(175.0), 0.0)
    text = re.sub(r"(?m)^max_velocity = \[[^,]*,", f"max_velocity = [{slow!r},", text)
    toml.write_text(text)
    assert math.degrees(slow) < 175.0
    assert max_speed_deviation(load_robot(toml)) == 175


def test_kit_command_writes_and_checks(tmp_path, capsys):
    toml = _toy_robot(tmp_path, TOY_HOME_DEG, TOY_VMAX_DEG)
    default = toml.parent / "controller"
    code, out, err = _compile_cli(capsys, "kit", str(toml), "--check")
    assert code == 1 and out.count(": missing") == 4, out
    assert "4 of 4 kit files differ" in err
    code, out, _ = _compile_cli(capsys, "kit", str(toml))
    assert code == 0 and out.count("wrote ") == 4 and (default / MOD.name).is_file()
    assert _compile_cli(capsys, "kit", str(toml), "--check")[0] == 0
    mod = default / MOD.name
    mod.write_text(mod.read_text().replace(":= 131;", ":= 120;"))  # edited by hand
    code, out, err = _compile_cli(capsys, "kit", str(toml), "--check")
    assert code == 1 and out.strip() == f"{mod}: differs from what robot.toml gives"
    other = tmp_path / "elsewhere"
    code, out, _ = _compile_cli(capsys, "kit", str(toml), "-o", str(other))
    assert code == 0 and sorted(p.name for p in other.iterdir()) == sorted(
        [MOD.name, SIO.name, MOC.name, "README.md"]
    )
    assert _compile_cli(capsys, "kit", str(toml), "-o", str(other), "--check")[0] == 0


def test_kit_needs_a_home(tmp_path, capsys):
    toml = _toy_robot(tmp_path, TOY_HOME_DEG, TOY_VMAX_DEG)
    toml.write_text(re.sub(r"(?m)^home = \[.*\]$", "", toml.read_text()))
    code, _, err = _compile_cli(capsys, "kit", str(toml))
    assert code == 1 and "gives no home" in err and len(err.strip().splitlines()) == 1
