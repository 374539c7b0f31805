"""The garbage-collection rule shared by the daemon's loop, its reply process and the decision
benchmark: held at start, the interpreter's thresholds applied by hand, at most ``oldest``."""

import gc

import pytest

from thinkfast.link import gc_rule


@pytest.fixture
def held():
    limits = gc.get_threshold()
    gc_rule.hold()
    try:
        yield
    finally:
        gc_rule.release()
        gc.set_threshold(*limits)


def _collections() -> list[int]:
    return [s["collections"] for s in gc.get_stats()]


def _fill(n: int) -> list:
    return [[] for _ in range(n)]  # containers: each counts in generation 0


def test_hold_freezes_the_heap_and_stops_automatic_collection(held):
    assert not gc.isenabled() and gc.get_freeze_count() > 0
    before = _collections()
    keep = _fill(5000)  # far over the threshold: nothing collects by itself
    assert _collections() == before and keep


def test_release_undoes_hold():
    gc_rule.hold()
    gc_rule.release()
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_nothing_is_collected_below_the_first_threshold(held):
    gc.set_threshold(1000, 10, 10)
    gc.collect()  # counts start at 0
    before = _collections()
    keep = _fill(100)
    gc_rule.collect_due()
    assert _collections() == before and keep


@pytest.mark.parametrize(("young", "middle", "expected"), [(0, 0, 0), (10, 0, 1), (10, 10, 2)])
def test_the_generation_collected_is_the_interpreters(held, young, middle, expected):
    gc.set_threshold(50, 3, 3)
    gc.collect()
    keep = []
    for _ in range(middle * 3):  # generation-1 collections raise generation 2's count
        keep += _fill(60)
        gc.collect(1)
    for _ in range(young and 3):  # generation-0 collections raise generation 1's count
        keep += _fill(60)
        gc.collect(0)
    keep += _fill(60)
    before = _collections()
    gc_rule.collect_due()
    after = _collections()
    assert [a - b for a, b in zip(after, before, strict=True)] == [
        int(g == expected) for g in range(3)
    ]


def test_oldest_caps_the_generation(held):
    gc.set_threshold(50, 3, 3)
    gc.collect()
    keep = []
    for _ in range(9):
        keep += _fill(60)
        gc.collect(1)
    for _ in range(3):
        keep += _fill(60)
        gc.collect(0)
    keep += _fill(60)
    before = _collections()
    gc_rule.collect_due(oldest=1)
    after = _collections()
    assert [a - b for a, b in zip(after, before, strict=True)] == [0, 1, 0]
