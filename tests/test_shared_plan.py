"""The plan seqlock and the reply row ring, between real processes."""

from __future__ import annotations

import multiprocessing

import numpy as np

from thinkfast.reply.shared_plan import RowRing, Seqlock

SIZE = 512


def _writer(name: str, n: int) -> None:
    block = Seqlock(SIZE, name)
    for k in range(1, n + 1):
        block.write(np.full(SIZE, float(k)))  # every value of write k is k
        block.beat(float(k))
    block.close()


def test_a_reader_never_gets_a_torn_write_from_another_process():
    block = Seqlock(SIZE)
    try:
        ctx = multiprocessing.get_context("spawn")
        writer = ctx.Process(target=_writer, args=(block.name, 200_000))
        writer.start()
        reads, last = 0, 0.0
        while writer.is_alive() or reads == 0:
            got = block.read()
            if got is None:
                continue
            version, values = got
            assert version % 2 == 0
            if np.isnan(values[0]):
                continue  # before the first write
            reads += 1
            assert np.all(values == values[0]), "a torn write was returned"
            assert values[0] >= last  # writes are seen in order
            last = values[0]
        writer.join()
        assert writer.exitcode == 0
        assert block.read()[1][0] == 200_000.0 and block.heartbeat == 200_000.0
        assert reads > 0
    finally:
        block.close()


def test_a_torn_block_is_never_returned_while_a_write_is_under_way():
    block = Seqlock(4)
    try:
        block.write(np.ones(4))
        block._counter[0] += 1  # a writer stopped half way (odd counter)
        block._data[:2] = 2.0
        assert block.read(tries=10) is None
        block._counter[0] += 1
        version, values = block.read()
        assert version == 4 and list(values) == [2.0, 2.0, 1.0, 1.0]
    finally:
        block.close()


def test_the_ring_keeps_order_and_counts_rows_overwritten_before_they_were_read():
    ring = RowRing(3, rows=16)
    try:
        reader = RowRing(3, rows=16, name=ring.name)
        for k in range(5):
            ring.put(np.array([k, k, k], dtype=float))
        assert reader.take()[:, 0].tolist() == [0, 1, 2, 3, 4]
        for k in range(5, 45):
            ring.put(np.array([k, k, k], dtype=float))
        rows = reader.take()
        assert rows[:, 0].tolist() == list(range(30, 45))  # the newest 15 (one slot spared)
        assert reader.lost == 25
        assert len(reader.take()) == 0
        reader.close()
    finally:
        ring.close()


_SMALL_DISK = """
import resource, sys
resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))
from thinkfast.reply.shared_plan import RowRing
from thinkfast.errors import ThinkfastError
try:
    RowRing(32)
except ThinkfastError as e:
    print(e)
    sys.exit(3)
"""


def test_shared_memory_that_cannot_be_made_is_a_clear_error_not_an_internal_one():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _SMALL_DISK], capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert out.returncode == 3, out.stderr
    assert "--reply-process" in out.stdout and "/dev/shm" in out.stdout
    assert "File too large" in out.stdout
