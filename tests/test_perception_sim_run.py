"""``thinkfast-sim run --frames``: rendered frames -> thinkfast-detect -> the daemon, end to end."""

import json

import pytest
from conftest import assert_one_line_error, compile_small_tree, run_cli


@pytest.mark.realtime
def test_sim_run_with_frames_blocks_through_the_detector(tmp_path):
    tree = compile_small_tree(tmp_path, spacing=0.15)  # shared with small_tree_015
    proc = run_cli(
        "thinkfast-sim", "run", "--tree", str(tree), "--throws", "1", "--seed", "3", "--frames",
        "--planner", "naive", timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert "camera frames (hd720) via thinkfast-detect" in lines[0]
    assert lines[1].startswith("throw   1/1")
    counts = json.loads(
        next(x for x in lines if x.startswith("thinkfast-detect: ")).split(": ", 1)[1]
    )
    frames = counts["frames"]
    assert sum(frames["rejected"].values()) == 0
    # the ball is in view from the hand to about 0.35 m before the plane: most frames see it
    assert frames["detected"] >= 0.6 * frames["received"] > 10
    assert counts["published"] == frames["detected"]
    assert lines[-1].startswith("naive: blocked ")


def test_sim_run_refuses_a_bad_detector_config_before_starting(tmp_path):
    bad = tmp_path / "d.toml"
    bad.write_text("[cloud]\nball_radius = -1\n")
    proc = run_cli(
        "thinkfast-sim", "run", "--tree", "x.h5", "--frames", "--detect-config", str(bad),
        timeout=60,
    )  # fmt: skip
    assert_one_line_error(proc, "cloud.ball_radius")
