"""EGM cycle timing: when the daemon's loop sleeps, spins, prepares the next reply and works."""

import math

import pytest

from thinkfast.link.cycle import PREPARE_AHEAD, SILENT, SPIN_LATE, WORK_GUARD, Cycle

DT = 0.004


def test_without_spinning_the_loop_naps_1_ms_and_prepares_1_ms_ahead():
    c = Cycle(DT)
    assert not c.busy and c.ahead == PREPARE_AHEAD
    assert all(c.wait_ms(s) == 1 for s in (0.0, 0.0029, 0.0035, 0.0041, 0.1))
    assert not c.in_window(DT - PREPARE_AHEAD - 1e-6) and c.in_window(DT - PREPARE_AHEAD)
    assert c.in_window(DT + SPIN_LATE) and not c.in_window(DT + SPIN_LATE + 1e-6)


def test_spinning_ahead_never_sleeps_into_the_window_and_naps_again_after_it():
    c = Cycle(DT, spin_ahead=0.001)
    opens = DT - 0.001
    assert c.ahead == 0.001 and c.in_window(opens) and not c.in_window(opens - 1e-6)
    for since in (0.0, 0.001, opens - 0.001):  # a whole millisecond before the window: nap
        assert c.wait_ms(since) == 1
    for since in (opens - 0.001 + 1e-6, opens, DT, DT + SPIN_LATE):  # else spin until it comes
        assert c.wait_ms(since) == 0
    assert c.wait_ms(DT + SPIN_LATE + 1e-6) == 1  # a late or silent controller: nap


def test_busy_polling_spins_always_and_keeps_the_default_window():
    c = Cycle(DT, spin_ahead=math.inf)
    assert c.busy and c.ahead == PREPARE_AHEAD
    assert all(c.wait_ms(s) == 0 for s in (0.0, 0.003, 0.01, 1.0))


@pytest.mark.parametrize("spin_ahead", [0.0, 0.0002, 0.001, 0.002, math.inf])
def test_other_work_ends_before_the_window_opens_and_guard_before_the_packet(spin_ahead):
    c = Cycle(DT, spin_ahead)
    for since in (0.0, 0.001, 0.002, 0.003):
        left = c.time_left(since)
        if left > 0.0:  # work of that length started now ends in time
            end = since + left
            assert end <= DT - c.ahead + 1e-12 and end <= DT - WORK_GUARD + 1e-12
        else:
            assert since >= DT - max(c.ahead, WORK_GUARD) - 1e-12
    assert c.time_left(0.0) == pytest.approx(DT - max(WORK_GUARD, c.ahead))
    assert c.time_left(SILENT + 1e-6) == math.inf  # the controller is silent: work at will
