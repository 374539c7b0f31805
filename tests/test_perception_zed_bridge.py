"""``thinkfast-zed`` end to end: the stand-in SDK (tests/zed_standin.py, installed as
``pyzed.sl``) grabbed by the real CLI, frames published on a real zenoh session on loopback and
decoded by the detector's own decoder; the camera mode of the config reaches InitParameters; no
SDK: one line naming it, exit 2."""

import importlib.util
import json
import os
import signal
import subprocess
import sys
import threading
import types

import numpy as np
import pytest
import zed_standin
from conftest import ROOT

from thinkfast.contract import keys
from thinkfast.contract.zenoh_session import free_tcp_port, open_peer
from thinkfast.perception.config import DetectConfig, ZedConfig
from thinkfast.perception.frame import Frame, parse_frame
from thinkfast.perception.zed import image_to_camera
from thinkfast.perception.zed_bridge import ZedError, init_parameters
from thinkfast.perception.zed_cli import main

LOOPBACK = ROOT / "thinkfast/sim/loopback_zenoh.json5"
WANT = 12  # frames the test collects before it stops the bridge


@pytest.fixture
def sdk(monkeypatch):
    """The stand-in installed as ``pyzed.sl`` (and its records cleared)."""
    zed_standin.opened.clear()
    zed_standin.cameras.clear()
    pkg = types.ModuleType("pyzed")
    pkg.sl = zed_standin
    monkeypatch.setitem(sys.modules, "pyzed", pkg)
    monkeypatch.setitem(sys.modules, "pyzed.sl", zed_standin)
    return zed_standin


def run_main(argv: list[str]) -> int:
    """The CLI in this process; its exit code (signal handlers restored afterwards)."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(SystemExit) as exc:
            main(argv)
        return exc.value.code
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


def test_bridge_publishes_the_sdk_frames_in_si_units_in_the_configured_mode(sdk, tmp_path, capsys):
    conf = tmp_path / "detect.toml"
    conf.write_text(
        '[camera]\nmode = "VGA"\nfps = 100.0\n[zed]\ndepth_mode = "QUALITY"\nstamp_lag = 0.02\n'
    )
    port = free_tcp_port()
    session = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    got: list[bytes] = []

    def on_frame(sample):  # only collects; SIGINT stops the bridge as a user's Ctrl-C would
        got.append(sample.payload.to_bytes())
        if len(got) == WANT:
            os.kill(os.getpid(), signal.SIGINT)

    sub = session.declare_subscriber(keys.camera_frame("zt", "left"), on_frame)
    watchdog = threading.Timer(60.0, os.kill, (os.getpid(), signal.SIGINT))
    watchdog.start()
    try:
        code = run_main(["--config", str(conf), "--key-prefix", "zt", "--camera", "left",
                         "--serial", "31234567", "--zenoh-config", str(LOOPBACK),
                         "--zenoh-connect", f"tcp/127.0.0.1:{port}"])  # fmt: skip
    finally:
        watchdog.cancel()
        sub.undeclare()
        session.close()
    assert code == 0
    assert len(got) >= WANT
    init = sdk.opened[0]
    assert init.camera_resolution == sdk.RESOLUTION.VGA and init.camera_fps == 100
    assert init.depth_mode == sdk.DEPTH_MODE.QUALITY
    assert init.coordinate_units == sdk.UNIT.MILLIMETER
    assert init.coordinate_system == sdk.COORDINATE_SYSTEM.IMAGE
    assert init.serial_number == 31234567
    assert all(cam.closed for cam in sdk.cameras)
    w, h = sdk.SIZES[sdk.RESOLUTION.VGA]
    frames = [parse_frame(p) for p in got]
    assert all(isinstance(f, Frame) for f in frames), frames[0]
    seqs = [f.seq for f in frames]
    assert seqs == sorted(set(seqs))  # in order (a live bridge may drop a frame: DROP)
    for f in frames:
        assert f.stamp == pytest.approx(sdk.stamp_ns(f.seq, 100) * 1e-9 - 0.02, abs=1e-6)
        assert (f.width, f.height) == (w, h) and (f.fx, f.cx) == (265.0, (w - 1) / 2.0)
        assert f.image.shape == (h, w, 3) and np.all(f.image[..., 2] == f.seq % 256)
        assert f.xyz.shape == (h, w, 3) and f.xyz.dtype == np.float16  # VGA: full resolution
        assert f.xyz_scale == 1.0
        depth = f.xyz[..., 0].astype(float)
        finite = np.isfinite(depth)
        assert np.allclose(depth[finite], sdk.depth_mm(f.seq) / 1000.0, rtol=1e-3)  # mm -> m
        want = image_to_camera(sdk.xyz_mm(sdk.RESOLUTION.VGA, f.seq), 1e-3)
        assert np.allclose(f.xyz.astype(np.float32), want, rtol=1e-3, equal_nan=True)
    counts = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert counts["grabbed"] == counts["published"] >= seqs[-1] and counts["grab_errors"] == 0


def test_the_zed_2i_mode_hd720_at_60_fps_from_the_config_runs_as_set_without_a_warning(
    sdk, tmp_path, capsys
):
    """A rate the ZED 2i runs at HD720 (60): the camera opens at it, no warning, and the frames
    are HD720's (XYZ at half resolution by default), decoded by the detector's decoder."""
    conf = tmp_path / "detect.toml"
    conf.write_text('[camera]\nmode = "HD720"\nfps = 60.0\n[zed]\ndepth_mode = "ULTRA"\n')
    port = free_tcp_port()
    session = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    got: list[bytes] = []

    def on_frame(sample):  # only collects; SIGINT stops the bridge (as in the test above)
        got.append(sample.payload.to_bytes())
        if len(got) == 2:
            os.kill(os.getpid(), signal.SIGINT)

    sub = session.declare_subscriber(keys.camera_frame("zt"), on_frame)
    watchdog = threading.Timer(60.0, os.kill, (os.getpid(), signal.SIGINT))
    watchdog.start()
    try:
        code = run_main(["--config", str(conf), "--key-prefix", "zt",
                         "--zenoh-config", str(LOOPBACK),
                         "--zenoh-connect", f"tcp/127.0.0.1:{port}"])  # fmt: skip
    finally:
        watchdog.cancel()
        sub.undeclare()
        session.close()
    assert code == 0 and len(got) >= 2
    init = sdk.opened[0]
    assert init.camera_resolution == sdk.RESOLUTION.HD720 and init.camera_fps == 60
    assert init.depth_mode == sdk.DEPTH_MODE.ULTRA and sdk.cameras[0].fps == 60
    err = capsys.readouterr().err
    assert "HD720 at 60 fps, depth ULTRA -> zt/camera/frame" in err and "warning" not in err, err
    frame = parse_frame(got[-1])
    assert isinstance(frame, Frame), frame
    assert (frame.width, frame.height) == (1280, 720) and frame.fx == 532.0
    assert frame.image.shape == (720, 1280, 3) and frame.xyz.shape == (360, 640, 3)
    assert frame.stamp == pytest.approx(sdk.stamp_ns(frame.seq, 60) * 1e-9, abs=1e-6)


def test_a_depth_mode_the_sdk_lacks_names_the_key(sdk):
    old = types.SimpleNamespace(**vars(sdk))
    old.DEPTH_MODE = types.SimpleNamespace(PERFORMANCE=1, QUALITY=2, ULTRA=3)
    old.DEPTH_MODE.__name__ = "DEPTH_MODE"
    cfg = DetectConfig(zed=ZedConfig(depth_mode="NEURAL"))
    with pytest.raises(ZedError, match=r"zed.depth_mode = 'NEURAL'.*DEPTH_MODE.NEURAL"):
        init_parameters(old, cfg)


def test_a_camera_that_does_not_open_is_one_line_exit_1(sdk, monkeypatch, capsys):
    monkeypatch.setattr(sdk.Camera, "open", lambda self, init: sdk.ERROR_CODE.CAMERA_NOT_DETECTED)
    assert run_main(["--zenoh-config", str(LOOPBACK)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "CAMERA_NOT_DETECTED" in err[0], err


def test_a_rate_the_camera_does_not_run_is_warned_naming_camera_fps(sdk, tmp_path, capsys):
    conf = tmp_path / "detect.toml"
    conf.write_text('[camera]\nmode = "HD720"\nfps = 50.0\n')  # the ZED 2i runs 60 at HD720
    assert run_main(["--config", str(conf), "--zenoh-config", str(LOOPBACK), "--frames", "2"]) == 0
    assert sdk.opened[0].camera_fps == 50
    err = capsys.readouterr().err
    assert "runs at 60 fps, not camera.fps = 50: set camera.fps = 60" in err, err


def test_without_the_sdk_one_line_names_it_and_where_to_get_it_exit_2(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyzed", None)
    monkeypatch.setitem(sys.modules, "pyzed.sl", None)
    assert run_main([]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ZED SDK" in err[0] and "stereolabs.com" in err[0], err


@pytest.mark.skipif(importlib.util.find_spec("pyzed") is not None, reason="pyzed is installed")
def test_without_the_sdk_the_real_process_exits_2_without_a_traceback():
    env = dict(os.environ)
    env.pop("THINKFAST_DEBUG", None)
    proc = subprocess.run([sys.executable, "-m", "thinkfast.perception.zed_cli"],
                          capture_output=True, text=True, timeout=120, env=env)  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert lines[0].startswith("thinkfast-zed: error:") and "ZED SDK" in lines[0]
