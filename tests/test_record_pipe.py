"""The pipe to the writer process: a writer that is not ready in time is stopped and named as
late, not as a process that died of a signal."""

from __future__ import annotations

import pytest

from thinkfast.errors import RecorderError
from thinkfast.record.pipe import WriterPipe


def test_a_writer_not_ready_in_time_is_reported_as_late(tmp_path):
    path = tmp_path / "rec.h5"
    with pytest.raises(RecorderError) as err:
        WriterPipe(path, {}, 1 << 16, timeout=0.0)  # no time at all to answer
    assert str(path) in str(err.value) and "not ready within 0 s" in str(err.value)
    assert "signal" not in str(err.value)


def test_a_ready_writer_is_taken_and_closes(tmp_path):
    pipe = WriterPipe(tmp_path / "rec.h5", {}, 1 << 16, timeout=60.0)
    assert pipe.last.get("ready")
    pipe.kill()


def test_a_writer_started_early_is_the_one_the_pipe_takes(tmp_path):
    """``start_writer_early`` (the daemon's first step with --record): the pipe for that path
    takes the process already started instead of starting another."""
    from thinkfast.record import pipe as pipe_module

    path = tmp_path / "rec.h5"
    pipe_module.start_writer_early(path)
    early = pipe_module._early[str(path.resolve())][0]
    pipe = WriterPipe(path, {}, 1 << 16, timeout=60.0)
    assert pipe.proc is early and pipe.last.get("ready") and path.exists()
    assert str(path.resolve()) not in pipe_module._early
    pipe.kill()
