"""``--foxglove`` on the simulator and on replay, each received by an independent WebSocket
client (tests/foxglove_client.py: the protocol, protobuf and CDR decoded from what the server
advertises). ``thinkfast-sim run --foxglove`` hands the option to the daemon it starts (the
daemon's view: its scheduler, its painter); ``thinkfast-sim replay RECORD --foxglove``
(thinkfast/view/foxglove_replay.py) plays that run's flight record at its pace, and the client
gets the MCAP's scene messages byte for byte and the record's joints and events."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websocket")

from tests.foxglove_client import listen, protobuf_class, ros2_decoder  # noqa: E402
from thinkfast.contract.zenoh_session import free_tcp_port  # noqa: E402
from thinkfast.record.format import read_record  # noqa: E402
from thinkfast.record.tables import columns  # noqa: E402
from thinkfast.view.channels import scene_messages  # noqa: E402
from thinkfast.view.foxglove_replay import Played, play  # noqa: E402
from thinkfast.view.replay import decimate, plane_and_goals  # noqa: E402
from thinkfast.view.scene import SCENE_TOPIC  # noqa: E402

BIN = Path(sys.executable).parent
START = 180.0  # s: time limits for a slow host (waits end on conditions, far sooner)
CROSSING = re.compile(r"crossing \(([-+]\d+\.\d+), (\d+\.\d+)\) m -> (\w+)")
PLAYED = re.compile(r"played (\d+) messages")


def _serve(args: list[str], port: int, log: Path, n_channels: int, arrivals=None):
    """Run ``thinkfast-sim ARGS`` while the client listens on ``port``: until it exits, or
    (a replay) until the client has every message the replay says it played (then the client
    leaves, and the replay ends)."""
    with open(log, "w") as out:
        proc = subprocess.Popen([str(BIN / "thinkfast-sim"), *args], stdout=out, stderr=out)
        try:
            alive = lambda: proc.poll() is None  # noqa: E731

            def until(got) -> bool:
                played = PLAYED.search(log.read_text())
                n = sum(len(v) for v in got.values())
                return not alive() or (played is not None and n >= int(played.group(1)))

            channels, got = listen(port, until, START, n_channels, alive, arrivals)
            code = proc.wait(START)
        finally:
            if proc.poll() is None:
                proc.kill()
            print(log.read_text())  # shown when the test fails
    return code, log.read_text(), channels, got


@pytest.fixture(scope="module")
def sim_run(small_tree_015, tmp_path_factory):
    """``thinkfast-sim run --throws 1 --record R --foxglove 127.0.0.1:P`` heard by the client:
    (exit status, output, record, channels, messages)."""
    d = tmp_path_factory.mktemp("foxglove_sim")
    port, record = free_tcp_port(), d / "run.h5"
    args = ["run", "--tree", str(small_tree_015), "--throws", "1", "--seed", "2", "--record",
            str(record), "--foxglove", f"127.0.0.1:{port}"]  # fmt: skip
    code, out, channels, got = _serve(args, port, d / "out.txt", 10)
    return code, out, record, channels, got


@pytest.mark.realtime
def test_the_simulator_serves_its_daemons_live_scene(sim_run, robot):
    code, out, record, channels, got = sim_run
    assert code == 0, out
    assert re.search(r"live view in Foxglove: ws://127\.0\.0\.1:\d+", out), out
    y, z, verdict = CROSSING.search(out).groups()  # the simulated ball's true crossing
    assert {"/thinkfast/scene", "/thinkfast/status", "/thinkfast/ball/crossing"} <= set(channels)

    joints = ros2_decoder(channels["/thinkfast/joints/commanded"])
    first = joints(got["/thinkfast/joints/commanded"][0][1])
    assert first.header.frame_id == "base_link" and len(first.position) == 6

    # every predicted crossing drawn live is the record's for that detection, and the last
    # ones close on where the simulated ball crossed
    crossing = ros2_decoder(channels["/thinkfast/ball/crossing"])
    live = [crossing(m) for _, m in got["/thinkfast/ball/crossing"]]
    assert len(live) >= 5, out
    b = columns(read_record(record), "beliefs")
    for m in live:
        t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
        i = int(np.argmin(np.abs(b["t"] - t)))
        assert abs(b["t"][i] - t) < 1e-6 and b["crossing_ok"][i] > 0.5
        assert (m.point.y, m.point.z) == pytest.approx(tuple(b["o_mean"][i, :2]), abs=1e-9)
    near = [np.hypot(m.point.y - float(y), m.point.z - float(z)) for m in live[-5:]]
    assert min(near) < 0.1, (near, out)

    scene = protobuf_class(channels["/thinkfast/scene"])
    ids = {e.id for _, msg in got["/thinkfast/scene"] for e in scene.FromString(msg).entities}
    assert {"arm_commanded", "arm_measured", "ball", "crossing", "plan", "goals"} <= ids


@pytest.mark.realtime
def test_replay_plays_the_record_at_its_pace_as_the_mcap_draws_it(
    sim_run, small_tree_015, robot, tmp_path
):
    record = sim_run[2]
    rec = read_record(record)
    port, arrivals, speed = free_tcp_port(), [], 2.0
    args = ["replay", str(record), "--foxglove", f"127.0.0.1:{port}", "--speed", str(speed),
            "--tree", str(small_tree_015)]  # fmt: skip
    code, out, channels, got = _serve(args, port, tmp_path / "out.txt", 9, arrivals)
    assert code == 0, out
    assert "/thinkfast/status" not in channels  # a record keeps no status

    # the scene: the MCAP's messages (same painter, same record), in order, byte for byte
    want = scene_messages(rec, robot, *plane_and_goals(rec, small_tree_015))
    assert [d for _, d in got[SCENE_TOPIC]] == [d for _, _, d in want]
    assert [ns for ns, _ in got[SCENE_TOPIC]] == [int(t * 1e9) for t, _, _ in want]

    # the joints: the record's EGM rows at 50 per second, decoded by the advertised definition
    egm = columns(rec, "egm")
    keep = decimate(egm["t"], 50.0)
    joints = ros2_decoder(channels["/thinkfast/joints/commanded"])
    msgs = [joints(m) for _, m in got["/thinkfast/joints/commanded"]]
    assert len(msgs) == len(keep) > 10
    np.testing.assert_array_equal([m.position for m in msgs], egm["q_cmd"][keep])
    assert len(got["/thinkfast/events"]) == len(rec.events) > 0

    # at the record's pace: the last message went out (t_last - t_first) / speed after the
    # first (a lower bound: a slow host only stretches it)
    span = (want[-1][0] - want[0][0]) / speed
    assert span > 1.0 and arrivals[-1] - arrivals[0] >= 0.5 * span, (span, out)


def test_play_keeps_an_absolute_schedule():
    """Calls go out at start + (t - t0) / speed; a late one goes out at once, the next on time."""
    now = [0.0]
    made: list = []

    class Painter:
        def arm(self, t, which):
            made.append((now[0], t, which))
            if which == "slow":
                now[0] += 0.5  # this call takes 0.5 s

    def sleep(s):
        now[0] += s

    calls = [(10.0, "arm", ("a",)), (10.2, "arm", ("slow",)), (10.4, "arm", ("b",)),
             (11.6, "arm", ("c",))]  # fmt: skip
    done = play(calls, Painter(), speed=2.0, clock=lambda: now[0], sleep=sleep)
    assert [m[0] for m in made] == pytest.approx([0.0, 0.1, 0.6, 0.8])  # "b" due at 0.2: late
    assert [m[1:] for m in made] == [(t, a[0]) for t, _, a in calls]
    assert isinstance(done, Played) and done.calls == 4 and done.max_late == pytest.approx(0.4)


@pytest.mark.parametrize(
    "args",
    [
        ["replay", "r.h5", "--foxglove", "8765", "--zenoh-connect", "tcp/127.0.0.1:7447"],
        ["replay", "r.h5", "--foxglove", "host:port"],
        ["run", "--tree", "t.h5", "--foxglove", "8765", "--rerun", "spawn"],
        ["run", "--tree", "t.h5", "--foxglove", "8765", "--egm", "127.0.0.1:6510", "--zenoh",
         "tcp/127.0.0.1:7447"],
    ],
)  # fmt: skip
def test_a_wrong_foxglove_option_is_one_error_naming_it(args, capsys):
    from thinkfast.sim.cli import main as sim_main

    with pytest.raises(SystemExit) as exc:
        sim_main(args)
    assert exc.value.code == 1
    assert "--foxglove" in capsys.readouterr().err
