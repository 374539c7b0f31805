"""Velocity from position-only EGM feedback: spans on the controller's clock, three-point rate."""

import numpy as np

from thinkfast.control.feedback_rate import parabola_velocity, span_before

DT = 0.004


def test_three_packets_measure_the_velocity_of_a_constant_deceleration_exactly():
    v0, a = np.linspace(-1.0, 1.0, 6), np.full(6, -12.0)
    s = np.array([0.0, 0.004, 0.012])  # uneven: a packet missed
    track = [(t, 0.3 + v0 * t + 0.5 * a * t * t) for t in s]
    np.testing.assert_allclose(parabola_velocity(track), v0 + a * s[-1], atol=1e-9)
    standing = [(t, np.full(6, 0.7)) for t in s]
    assert not parabola_velocity(standing).any()  # exactly zero
    assert parabola_velocity([(0.0, v0), (0.0, v0), (0.004, v0)]) is None


def test_the_span_to_a_superseded_packet_counts_cycles_by_seqno_else_by_tm():
    q = np.zeros(6)
    assert span_before(1005, 11, (1000, q, 10), DT)[0] == DT  # tm said 5 ms: one cycle
    assert span_before(1008, None, (1000, q), DT)[0] == 0.008
    assert span_before(1020, 15, (1000, q, 10), DT) is None  # too far apart to measure
    assert span_before(1004, None, None, DT) is None
