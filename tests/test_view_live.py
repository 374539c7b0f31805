"""Live view with Rerun (thinkfast/view/live.py, docs/LIVE_VIEW.md): the --rerun option,
the geometry it draws, and a real simulated throw (daemon process, EGM over UDP, zenoh) saved to
an .rrd file and read back with the Rerun SDK."""

from __future__ import annotations

import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import compile_small_tree
from thinkfast.errors import ConfigError
from thinkfast.view.live import DEFAULT_CONNECT, ViewSink, parse_sink
from thinkfast.view.rerun_painter import ENTITIES

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    "text, sink",
    [
        ("spawn", ViewSink("spawn")),
        ("connect", ViewSink("connect", DEFAULT_CONNECT)),
        ("connect=rerun+http://10.0.0.2:9876/proxy",
         ViewSink("connect", "rerun+http://10.0.0.2:9876/proxy")),
        ("connect rerun+http://h:1/proxy", ViewSink("connect", "rerun+http://h:1/proxy")),
        ("save=/tmp/a.rrd", ViewSink("save", "/tmp/a.rrd")),
    ],
)  # fmt: skip
def test_the_rerun_option_names_a_sink(text, sink):
    assert parse_sink(text) == sink


@pytest.mark.parametrize("text", ["", "show", "save", "spawn=x", "save="])
def test_a_bad_rerun_option_is_one_error_naming_it(text):
    with pytest.raises(ConfigError, match="--rerun"):
        parse_sink(text)


def test_the_view_costs_nothing_when_off():
    """Without --rerun the daemon does not even import rerun."""
    code = (
        "import sys; import thinkfast.daemon.service, thinkfast.daemon.cli, thinkfast.sim.cli; "
        "print('rerun' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    import inspect

    from thinkfast.daemon.service import Daemon

    assert inspect.signature(Daemon).parameters["view"].default is None


def test_the_docs_list_every_entity():
    text = (ROOT / "docs" / "LIVE_VIEW.md").read_text(encoding="utf-8")
    text = text.split("## Entities", 1)[1].split("\n## ", 1)[0]
    documented = set(re.findall(r"^\| `([a-z_/]+)` \|", text, flags=re.M))
    assert documented == set(ENTITIES)


@pytest.fixture(scope="module")
def saved_throw(tmp_path_factory):
    """One real-time simulated throw at a real daemon started with --rerun save=FILE."""
    from thinkfast.control.config import RunConfig
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.realtime import run_with_daemon
    from thinkfast.sim.throws import ThrowConfig, sample_throws

    d = tmp_path_factory.mktemp("live_view")
    tree = compile_small_tree(d, depth=1, spacing=0.5)
    rrd = d / "throw.rrd"
    balls = sample_throws(ThrowConfig(), 1, seed=1)
    res = run_with_daemon(
        tree, "tree", load_robot(), balls, 1, RunConfig().camera, report=lambda s: None,
        daemon_args=("--rerun", f"save={rrd}"),
    )  # fmt: skip
    assert len(res) == 1
    return rrd


def _read(rrd: Path) -> tuple[Counter, dict]:
    import rerun as rr

    rows, cols = Counter(), {}
    for c in rr.chunk.RrdReader(rrd).stream():
        path = c.entity_path.lstrip("/")
        rows[path] += c.num_rows
        batch = c.to_record_batch()
        cols.setdefault(path, set()).update(n for n in batch.schema.names if ":" in n)
        if path == "joints/q_cmd" and "time" in batch.schema.names:
            ns = batch.column("time").cast("int64").to_numpy()
            cols.setdefault("_t", []).extend((ns * 1e-9).tolist())
    return rows, cols


@pytest.mark.realtime
def test_a_simulated_throw_saved_to_rrd_holds_every_live_entity(saved_throw):
    pytest.importorskip("rerun")
    rows, cols = _read(saved_throw)
    live = set(ENTITIES) - {"events"}  # events: record replay only
    missing = [e for e in sorted(live) if rows[e] == 0]
    assert not missing, f"missing entities: {missing}; have {sorted(rows)}"
    assert "Ellipsoids3D:half_sizes" in cols["world/ball/covariance"]
    assert "Ellipsoids3D:half_sizes" in cols["world/plane/crossing"]
    assert "Cylinders3D:radii" in cols["world/arm/measured/shield"]
    assert "LineStrips3D:strips" in cols["world/plan/shield_path"]
    assert rows["world/detections/raw"] >= rows["world/detections/accepted"] > 10
    # joints are rate-limited to 50 Hz (the EGM stream is 250 Hz)
    t = sorted(cols["_t"])
    rate = (len(t) - 1) / (t[-1] - t[0])
    assert rate <= 52.0 and len(t) >= 2, (rate, len(t))  # fewer when its steps wait for time


def test_a_view_step_runs_only_when_its_measured_cost_fits_the_time_left(tmp_path):
    """The daemon passes the time left before the next EgmRobot's window: a step whose kind's
    measured cost exceeds it waits (counted, its cost decaying), and runs (measured again) once
    it fits or the controller is silent (unbounded budget). Real painter, real .rrd."""
    pytest.importorskip("rerun")
    from types import SimpleNamespace

    from thinkfast.control.config import RunConfig
    from thinkfast.robot.model import load_robot
    from thinkfast.view.live import DaemonView, open_stream, parse_sink
    from thinkfast.view.rerun_painter import Painter

    robot = load_robot()
    rec = open_stream(parse_sink(f"save={tmp_path / 'v.rrd'}"), "gate")
    painter = Painter(rec, robot, 0.8, np.zeros((0, 2)))
    view = DaemonView(painter, RunConfig(), tree_view=None)
    reply = SimpleNamespace(q=robot.home, qd=np.zeros(6))  # what the control core exposes
    control = SimpleNamespace(last=reply, measured=(0.0, robot.home))
    view.cost["timelines"] = 0.5  # s: a kind of step that was once very slow
    view.service(1.0, 1.0, control, budget=0.002)
    assert (view.done, view.waited) == (0, 1) and view.cost["timelines"] < 0.5
    assert [k for k, _ in view.steps] == ["timelines", "arm", "arm"]  # the job, cut in steps
    decayed = view.cost["timelines"]
    view.service(1.0, 1.0, control, budget=float("inf"))  # the controller is silent
    assert view.done == 1 and view.cost["timelines"] > 0.0
    assert view.cost["timelines"] != decayed  # measured again when it ran
    while view.steps:
        view.service(1.0, 1.0, control, budget=float("inf"))
    status = view.as_dict()
    assert status["done"] == 3 and status["waited"] == 1 and status["queued"] == 0
    assert set(status["cost_ms"]) == {"timelines", "arm"}
    view.close()
