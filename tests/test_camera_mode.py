"""The ZED 2i's video mode (thinkfast.contract.camera_mode): the ``[camera] mode`` and ``fps``
keys of the run and detector configurations, validated with the key named."""

from __future__ import annotations

import pytest

from thinkfast.contract.camera_mode import ZED_MODES, CameraSetup, check_camera_setup
from thinkfast.control.config import RunConfig, load_run_config
from thinkfast.errors import ConfigError
from thinkfast.perception.config import load_detect_config


def _write(tmp_path, text):
    path = tmp_path / "c.toml"
    path.write_text(text)
    return path


def test_default_is_hd720_at_the_papers_50_fps_in_both_configs():
    cam = RunConfig().camera
    assert (cam.mode, cam.fps, cam.frame_interval(), cam.focal_scale()) == ("HD720", 50.0, 0.02, 1)


def test_vga_pixels_are_about_twice_as_coarse_and_its_frames_twice_as_frequent(tmp_path):
    cam = load_run_config(_write(tmp_path, '[camera]\nmode = "VGA"\nfps = 100\n')).camera
    assert cam.focal_scale() == pytest.approx(532.0 / 265.0)
    assert cam.frame_interval() == pytest.approx(0.01)
    assert cam.xyz == CameraSetup().xyz  # the pose keys keep their defaults


@pytest.mark.parametrize("load", [load_run_config, load_detect_config])
@pytest.mark.parametrize(
    "body, key, problem",
    [
        (
            'mode = "HD720"\nfps = 100\n',
            "camera.fps",
            "HD720 runs at most 60 fps (VGA runs at 100)",
        ),
        ('mode = "VGA"\nfps = 120\n', "camera.fps", "VGA runs at most 100 fps"),
        ("fps = 0\n", "camera.fps", "must be > 0"),
        ('mode = "HD1080"\n', "camera.mode", "HD720"),
        ('mode = "vga"\n', "camera.mode", "VGA"),
    ],
)
def test_a_mode_or_rate_the_camera_cannot_do_is_refused_naming_the_key(
    tmp_path, load, body, key, problem
):
    path = _write(tmp_path, "[camera]\n" + body)
    with pytest.raises(ConfigError) as err:
        load(path)
    assert err.value.key == key and problem in str(err.value) and str(path) in str(err.value)


def test_every_mode_runs_at_its_top_rate_and_no_faster():
    for mode in ZED_MODES.values():
        assert check_camera_setup(CameraSetup(mode=mode.name, fps=mode.max_fps), "x").fps > 0
        with pytest.raises(ConfigError, match="camera.fps"):
            check_camera_setup(CameraSetup(mode=mode.name, fps=mode.max_fps + 1), "x")


def test_a_camera_file_may_carry_the_mode(tmp_path):
    (tmp_path / "camera.toml").write_text('[camera]\nxyz = [0.5, 0.0, 0.3]\nmode = "VGA"\n')
    cfg = load_run_config(_write(tmp_path, 'camera_file = "camera.toml"\n'))
    assert cfg.camera.mode == "VGA" and cfg.camera.xyz == (0.5, 0.0, 0.3)
