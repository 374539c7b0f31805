"""A first-light session on a real daemon (``--speed-scale 0.2 --record``) cut by SIGINT
mid-throw: the brake is logged and recorded, ``controller_state`` carries the controller's time,
and ``thinkfast-calib dynamics`` on that record measures the lag and changes no limit.

Everything is real (tests/daemon_harness.py): the daemon process, EGM over UDP with protobuf
from the simulated controller, zenoh on loopback, the recorder's HDF5 file.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tests.daemon_harness import DaemonRun, ballistic_throw, publish_throw
from thinkfast.calib.cli import main as calib_main
from thinkfast.calib.dynamics import estimate_from_record
from thinkfast.calib.dynamics_report import limit_verdicts
from thinkfast.control.config import load_run_config
from thinkfast.record.format import read_record

pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module")
def session(small_tree_015, robot, tmp_path_factory):
    """(record path, daemon log, exit code): a throw at 0.2x, a second cut by SIGINT."""
    rec = tmp_path_factory.mktemp("slow") / "cal.h5"
    run = DaemonRun(small_tree_015, rec, "tree", q0=robot.home, extra=("--speed-scale", "0.2"))
    try:
        for k in range(2):
            t_release = time.time() + 0.6
            _, _, at = ballistic_throw((0.25 - 0.2 * k, 1.25), 0.8, t_release)
            th = threading.Thread(target=publish_throw, args=(run, at, t_release, 0.8))
            th.start()
            if k == 1:  # SIGINT while the arm executes the second throw
                assert run.wait_state("executing", 5.0)
                time.sleep(0.3)
                break
            th.join()
            time.sleep(0.5)
            assert run.wait_state("idle", 15.0)  # 0.2x: the return home is slow
    finally:
        code, log = run.stop()
        th.join()
    return rec, log, code


def test_sigint_mid_throw_is_logged_and_recorded(session):
    rec, log, code = session
    assert code == 0
    assert "brake {" in log and '"reason": "signal"' in log and '"signal": "SIGINT"' in log
    brakes = [e for e in read_record(str(rec)).events if e.kind == "brake"]
    assert len(brakes) == 1
    # mid-throw: the ball is followed (seen once as "tracking" at the signal on an idle host,
    # not traced: the status had shown "executing" 0.3 s before)
    assert brakes[0].detail["reason"] == "signal"
    assert brakes[0].detail["mode"] in ("tracking", "executing")
    assert math.isfinite(brakes[0].t)


def test_controller_state_is_stamped_when_the_controller_reports_it(session):
    rec, _, _ = session
    r = read_record(str(rec))
    ev = next(e for e in r.events if e.kind == "controller_state")
    first_egm = r.tables["egm"][0, 0]
    assert math.isfinite(ev.t) and abs(ev.t - first_egm) < 0.1  # its packet's time, not before


def test_dynamics_on_a_slow_daemon_record_changes_no_limit(session, robot, tmp_path, capsys):
    rec, _, _ = session
    est = estimate_from_record(str(rec))
    assert est.segments >= 2 and 0.0 < est.lag < 0.1
    for j, d in enumerate(
        est.joints
    ):  # commanded within the 0.2x limits, on the controller's clock
        assert d.accel_cmd <= 0.2 * robot.a_max[j] * 1.1
    verdicts = limit_verdicts(est, robot.a_max, robot.j_max)
    assert {v.status for v in verdicts} == {"not measured"}
    patch = tmp_path / "patch.toml"
    with pytest.raises(SystemExit) as exc:
        calib_main(["dynamics", str(rec), "-o", str(patch)])
    assert exc.value.code == 0
    assert "no limit measured: robot.toml stays as it is" in capsys.readouterr().out
    assert load_run_config(patch).execution.controller_lag == pytest.approx(est.lag, abs=1e-4)
    assert "max_acceleration =" not in patch.read_text()
    gaps = np.diff(read_record(str(rec)).tables["egm"][:, 0])
    print(f"receive gaps {1e3 * gaps.min():.2f}..{1e3 * gaps.max():.1f} ms")


def test_the_start_log_names_the_fingerprint_compile_diff_prints(session, small_tree_015):
    _, log, _ = session
    start = json.loads(log.split(" start ", 1)[1].splitlines()[0])
    exe = Path(sys.executable).parent / "thinkfast-compile"
    out = subprocess.run(
        [str(exe), "diff", str(small_tree_015), str(small_tree_015)],
        capture_output=True, text=True, timeout=120, check=True,
    ).stdout  # fmt: skip
    shown = re.search(r"fingerprint ([0-9a-f]{16})", out).group(1)
    assert start["tree_fingerprint"] == shown
