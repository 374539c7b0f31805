"""Safety supervisor: whatever is requested, commands stay inside the limits and brake cleanly."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thinkfast.control.safety import BRAKE_REASONS, KINDS, SafetyConfig, SafetySupervisor
from thinkfast.control.safety_limits import beyond_envelope, make_limits
from thinkfast.errors import ThinkfastError

D = math.pi / 180.0
CFG = SafetyConfig()
DT = CFG.dt
LIM = make_limits(
    np.array([-180, -90, -245, -200, -115, -400]) * D,
    np.array([180, 120, 65, 200, 115, 400]) * D,
    np.array([180, 180, 185, 385, 400, 460]) * D,
    [12, 12, 15, 30, 30, 40],
    [120, 120, 150, 300, 300, 400],
    margin=CFG.position_margin,
)
TOL = 1e-9
PROPERTY = settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)


def assert_admissible(q, qd, q_prev, qd_prev, dt=DT):
    """The guarantees: finite, positions inside, |qd| <= v_max, |dqd/dt| <= a_max, recoverable."""
    assert np.isfinite(q).all() and np.isfinite(qd).all()
    assert (q >= LIM.q_min).all() and (q <= LIM.q_max).all()
    assert (np.abs(qd) <= LIM.v_max * (1 + TOL)).all()
    assert (np.abs(qd - qd_prev) / dt <= LIM.a_max * (1 + TOL)).all()
    stop = qd * qd / (2 * LIM.a_max) + 0.5 * np.abs(qd) * dt  # braking distance (safety_limits.py)
    assert (q + np.where(qd > 0, stop, 0) <= LIM.q_max + 1e-12).all()
    assert (q - np.where(qd < 0, stop, 0) >= LIM.q_min - 1e-12).all()


def _max_recoverable_speed(q):
    """Largest |v| towards the nearer limit that still brakes in time (per joint)."""
    room = np.minimum(LIM.q_max - q, q - LIM.q_min)
    a = LIM.a_max
    return np.minimum(LIM.v_max, a * (np.sqrt(0.25 * DT**2 + 2 * room / a) - 0.5 * DT))


def _start(q_frac, v_frac, brake=None):
    q0 = LIM.q_min + np.asarray(q_frac) * (LIM.q_max - LIM.q_min)
    sup = SafetySupervisor(LIM, CFG, q0)
    sup.qd = np.asarray(v_frac) * _max_recoverable_speed(q0) * 0.999
    if brake:
        sup.request_brake(brake)
    return sup


finite_or_not = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 1e300, -1e300, 1e6, -1e6, math.nan, math.inf, -math.inf]),
    st.floats(-4.0, 4.0),
)
vector = st.one_of(
    st.lists(finite_or_not, min_size=6, max_size=6),
    st.lists(st.floats(-4.0, 4.0), min_size=6, max_size=6),
    st.sampled_from([None, [1.0] * 5, "junk", [[0.0] * 6]]),
)
request = st.tuples(
    vector,
    vector,
    st.one_of(st.none(), st.lists(st.floats(-4.0, 4.0), min_size=6, max_size=6)),
    st.one_of(st.none(), st.floats(DT * (1 - 1e-4), DT * (1 + 1e-4))),
    st.one_of(st.none(), st.sampled_from(BRAKE_REASONS)),
)
fractions = st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6)
signed = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6)


@PROPERTY
@given(fractions, signed, st.lists(request, min_size=1, max_size=60))
def test_any_request_sequence_stays_inside_all_limits(q_frac, v_frac, requests):
    sup = _start(q_frac, v_frac)
    q_prev, qd_prev = sup.q.copy(), sup.qd.copy()
    for q_req, qd_req, q_meas, dt, brake in requests:
        if brake:
            sup.request_brake(brake)
        cmd = sup.step(q_req, qd_req, q_meas=q_meas, dt=dt)
        assert_admissible(cmd.q, cmd.qd, q_prev, qd_prev, DT if dt is None else dt)
        assert set(cmd.kinds) <= set(KINDS)
        q_prev, qd_prev = cmd.q, cmd.qd


def test_seeded_adversarial_requests_towards_the_limits_stay_admissible():
    """Long runs that chase the position limits at full speed: the case random floats rarely hit."""
    rng = np.random.default_rng(6)
    span = LIM.q_max - LIM.q_min
    for _ in range(40):
        sup = _start(rng.uniform(0, 1, 6), rng.uniform(-1, 1, 6))
        q_prev, qd_prev = sup.q.copy(), sup.qd.copy()
        for _ in range(300):
            pick = rng.integers(4)
            if pick == 0:  # beyond a limit, at speed
                q_req = np.where(rng.uniform(size=6) < 0.5, LIM.q_min, LIM.q_max) + rng.normal(
                    0, 0.3, 6
                )
                qd_req = np.sign(q_req - q_prev) * LIM.v_max * rng.uniform(0.5, 3, 6)
            elif pick == 1:  # plausible next state with an acceleration a bit too large
                qd_req = qd_prev + rng.uniform(-1.5, 1.5, 6) * LIM.a_max * DT
                q_req = q_prev + 0.5 * (qd_prev + qd_req) * DT
            elif pick == 2:  # jumps anywhere
                q_req, qd_req = LIM.q_min + rng.uniform(-0.1, 1.1, 6) * span, rng.normal(0, 5, 6)
            else:  # the previous command again
                q_req, qd_req = q_prev, qd_prev
            cmd = sup.step(q_req, qd_req)
            assert_admissible(cmd.q, cmd.qd, q_prev, qd_prev)
            q_prev, qd_prev = cmd.q, cmd.qd


@PROPERTY
@given(fractions, signed, st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6))
def test_braking_reaches_zero_velocity_within_limits(q_frac, v_frac, a_frac):
    sup = _start(q_frac, v_frac)
    sup.qdd = np.asarray(a_frac) * LIM.a_max
    a0 = np.clip(sup.qdd_end, -LIM.a_max, LIM.a_max)  # the acceleration the stop starts from
    sup.request_brake("signal")
    v0 = sup.qd.copy()
    # a joint turning round already (a against v, a^2 / 2j > |v|) passes zero by this much at
    # most and comes back; every other joint never reverses
    overshoot = np.maximum(a0 * a0 / (2 * LIM.j_max) - np.abs(v0), 0.0)
    overshoot[a0 * v0 > 0] = 0.0
    q_prev, qd_prev = sup.q.copy(), sup.qd.copy()
    # Worst case: ramp a_max down to -a_max, then brake from v_max: v/a + 3 a/j, plus slack.
    bound = int(np.max(LIM.v_max / LIM.a_max + 3 * LIM.a_max / LIM.j_max) / DT) + 10
    for _ in range(bound):
        cmd = sup.step(None, None)
        assert_admissible(cmd.q, cmd.qd, q_prev, qd_prev)
        assert (-cmd.qd * np.sign(v0) <= overshoot * (1 + 1e-6) + 1e-9).all()
        assert (np.abs(cmd.qd) <= np.abs(qd_prev) + LIM.a_max * DT * (1 + TOL)).all()
        q_prev, qd_prev = cmd.q, cmd.qd
        if cmd.stopped:
            break
    assert cmd.stopped and not cmd.qd.any()
    held = sup.step([0.0] * 6, [9.0] * 6)  # requests are ignored while braking
    assert not held.qd.any() and (held.q == cmd.q).all()


@PROPERTY
@given(signed)
def test_brake_from_cruise_respects_jerk_up_to_the_last_tick(v_frac):
    sup = _start([0.5] * 6, v_frac)
    sup.request_brake("signal")
    vs = [sup.qd.copy()]
    for _ in range(400):
        cmd = sup.step(None, None)
        vs.append(cmd.qd)
        if cmd.stopped:
            break
    acc = np.diff(vs, axis=0) / DT
    jerk = np.diff(np.vstack([np.zeros(6), acc]), axis=0) / DT
    assert (np.abs(acc) <= LIM.a_max * (1 + TOL)).all()
    assert (np.abs(jerk) <= 1.25 * LIM.j_max).all()


def test_admissible_smooth_trajectory_passes_unchanged():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    for k in range(1, 500):
        t = k * DT
        q = 0.5 * (1 - np.cos(np.pi * t)) * np.ones(6)
        qd = 0.5 * np.pi * np.sin(np.pi * t) * np.ones(6)
        cmd = sup.step(q, qd)
        assert cmd.kinds == () and (cmd.q == q).all() and (cmd.qd == qd).all()
    assert not any(sup.counts.values())


def test_a_jump_request_is_reached_smoothly_and_counted():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    target = np.full(6, 1.0)
    qd_prev = np.zeros(6)
    peak = np.zeros(6)
    for _ in range(400):
        cmd = sup.step(target, np.zeros(6))
        assert (np.abs(cmd.qd - qd_prev) <= LIM.a_max * DT * (1 + TOL)).all()
        qd_prev, peak = cmd.qd, np.maximum(peak, cmd.q)
    np.testing.assert_allclose(cmd.q, target, atol=1e-6)
    assert (peak <= target + 0.02).all()  # no large overshoot
    assert sup.counts["position_step"] > 0 and sup.counts["brake_nonfinite"] == 0


def test_request_beyond_a_limit_stops_at_the_margin():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    for _ in range(1000):
        cmd = sup.step(LIM.q_max + 1.0, np.zeros(6))
    np.testing.assert_allclose(cmd.q, LIM.q_max, atol=1e-6)
    assert sup.counts["position_limit"] > 0


@pytest.mark.parametrize(
    "kwargs, reason",
    [
        ({"q_meas": np.full(6, 1.0)}, "deviation"),
        ({"q_meas": [math.nan] * 6}, "deviation"),
        ({"q_meas": [0.0] * 5}, "deviation"),
    ],
)
def test_triggers_latch_a_brake_and_are_counted(kwargs, reason):
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    cmd = sup.step(np.zeros(6), np.zeros(6), **kwargs)
    assert cmd.braking and sup.brake_reason == reason and sup.counts[f"brake_{reason}"] == 1
    sup.release()
    assert not sup.step(np.zeros(6), np.zeros(6)).braking


def test_non_finite_request_brakes_and_is_counted():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    cmd = sup.step([0.0, 0.0, math.nan, 0.0, 0.0, 0.0], np.zeros(6))
    assert cmd.braking and cmd.kinds == ("nonfinite",)
    assert sup.counts["nonfinite"] == 1 and sup.counts["brake_nonfinite"] == 1
    assert np.isfinite(cmd.q).all()


def test_start_outside_the_margin_is_clipped_and_counted():
    sup = SafetySupervisor(LIM, CFG, LIM.q_max + 0.01)
    assert (sup.q == LIM.q_max).all() and sup.counts["init_clamped"] == 1


def test_the_supervisor_validates_its_start_and_brake_reason():
    with pytest.raises(ThinkfastError):
        SafetySupervisor(LIM, CFG, [0.0] * 5)
    with pytest.raises(ValueError, match="signal"):
        SafetySupervisor(LIM, CFG, np.zeros(6)).request_brake("because")


def test_a_step_filtered_ahead_gives_exactly_what_step_computes_and_counts_the_same():
    """filter_ahead() only moves the filter ahead: bit-identical commands and counts, random
    requests (admissible ones and wild ones) along one trajectory."""
    rng = np.random.default_rng(7)
    a, b = SafetySupervisor(LIM, CFG, np.zeros(6)), SafetySupervisor(LIM, CFG, np.zeros(6))
    for k in range(400):
        q_req = a.q + a.qd * DT + rng.normal(0.0, 0.02 if k % 7 else 2.0, 6)
        qd_req = a.qd + rng.normal(0.0, 0.05 if k % 5 else 5.0, 6)
        state = (a.q.copy(), a.qd.copy(), dict(a.counts), a.state)
        ahead = a.filter_ahead(q_req, qd_req)
        assert (a.q == state[0]).all() and (a.qd == state[1]).all()  # pure
        assert a.counts == state[2] and a.state == state[3] == ahead.state
        ca = a.step_ahead(ahead, q_meas=a.q)
        cb = b.step(q_req, qd_req, q_meas=b.q)
        assert ca.q.tobytes() == cb.q.tobytes() and ca.qd.tobytes() == cb.qd.tobytes()
        assert ca.kinds == cb.kinds and not ca.braking
    assert a.counts == b.counts and sum(a.counts.values()) > 0


def test_the_feedback_check_ahead_decides_as_the_deviation_does_at_the_threshold():
    """step_ahead checks the feedback in plain floats against the envelope filtered ahead:
    the same decision as deviation() > max_deviation, for feedback on either side of the
    threshold by one rounding step, non-finite and misshapen feedback included."""
    rng = np.random.default_rng(11)
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    braked = passed = 0
    for k in range(300):
        sup.step(sup.q + sup.qd * DT, sup.qd + rng.normal(0.0, 0.3 * LIM.a_max * DT, 6))
        ahead = sup.filter_ahead(sup.q, sup.qd)
        hi, lo, over = (np.array(b) for b in ahead.bounds)
        edge = np.where(rng.random(6) < 0.5, hi + over + CFG.max_deviation,
                        lo - over - CFG.max_deviation)  # fmt: skip
        q = sup.q.copy()
        j = k % 6
        q[j] = edge[j]
        for step in (-2, -1, 0, 1, 2):
            qj = q.copy()
            qj[j] = edge[j] + step * np.spacing(edge[j])
            dev = sup.deviation(qj)
            want = dev is None or bool((dev > CFG.max_deviation).any())
            assert beyond_envelope(qj, ahead.bounds, CFG.max_deviation) == want, (k, step)
            braked += want
            passed += not want
    for bad in ([math.nan] * 6, np.zeros(5), [0.0, 0.0, 0.0, 0.0, 0.0, math.inf]):
        assert beyond_envelope(bad, ahead.bounds, CFG.max_deviation)
    assert beyond_envelope(list(sup.q), ahead.bounds, CFG.max_deviation) is False
    assert braked > 100 and passed > 100


def test_a_step_filtered_ahead_is_not_used_after_the_state_changed_a_brake_or_another_tick():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    q_req, qd_req = np.full(6, 0.5), np.zeros(6)  # a jump: the filter limits it
    ahead = sup.filter_ahead(q_req, qd_req)
    sup.step(sup.q, np.zeros(6))  # a tick in between: the commanded state moved on
    assert ahead.state != sup.state
    sup.reset(np.zeros(6), np.full(6, 0.01))  # and now moves at 0.01 rad/s
    cmd = sup.step_ahead(ahead)
    assert np.allclose(cmd.qd - 0.01, LIM.a_max * DT)  # from the new state: +a_max dt
    ahead = sup.filter_ahead(q_req, qd_req)
    cmd = sup.step_ahead(ahead, q_meas=np.full(6, 1.0))  # feedback deviates: brake wins
    assert cmd.braking and sup.brake_reason == "deviation" and not cmd.kinds
    sup.release()
    ahead = sup.filter_ahead(q_req, qd_req)
    v0 = sup.qd
    cmd = sup.step_ahead(ahead, dt=DT * 1.0001)  # another tick length: computed afresh
    assert np.any(np.abs(cmd.qd - v0) > LIM.a_max * DT * 1.00005)
    ahead = sup.filter_ahead([math.nan] * 6, qd_req)  # nothing to filter: it brakes as step
    assert ahead.result is None
    assert sup.step_ahead(ahead).braking and sup.brake_reason == "nonfinite"


def _ramp(sup, v_target, n):
    """Accelerate every joint towards ``v_target`` [rad/s] at a_max/2 for ``n`` ticks (admissible
    requests, so the supervisor passes them unchanged)."""
    q, v = sup.q.copy(), sup.qd.copy()
    out = []
    for _ in range(n):
        v_new = v + np.clip(v_target - v, -0.5 * LIM.a_max * DT, 0.5 * LIM.a_max * DT)
        q = q + 0.5 * (v + v_new) * DT
        v = v_new
        out.append(sup.step(q, v))
    return out


def test_an_arm_lagging_its_command_within_the_tracking_lag_is_not_a_deviation():
    """The feedback of a servo that follows 0.15 s late (under tracking_lag) at full speed is
    inside the envelope of recent commands: no brake, however far it is from the newest one."""
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    lag = round(0.15 / DT)
    history = [sup.q] + [c.q for c in _ramp(sup, 0.8 * LIM.v_max, 150)]
    for _ in range(150):
        q_meas = history[max(0, len(history) - 1 - lag)]
        v = sup.qd
        cmd = sup.step(sup.q + v * DT, v, q_meas=q_meas)
        history.append(cmd.q)
        assert not cmd.braking
    assert np.max(np.abs(history[-1] - history[-1 - lag])) > 0.5  # far from the newest command


def test_an_arm_that_stops_following_brakes_on_deviation_after_the_lag_window():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    frozen = sup.q.copy()
    n_brake = None
    _ramp(sup, 0.8 * LIM.v_max, 200)
    for k in range(200):
        v = sup.qd
        cmd = sup.step(sup.q + v * DT, v, q_meas=frozen)
        if cmd.braking:
            n_brake = k
            break
    assert n_brake is not None and sup.brake_reason == "deviation"
    assert n_brake * DT <= CFG.tracking_lag + 0.01  # caught once the window has moved past it


def test_resync_starts_from_the_measured_state_and_counts():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    sup.request_brake("signal")
    q, v = np.full(6, 0.2), np.full(6, 0.1)
    assert sup.resync(q, v) and not sup.braking
    assert (sup.q == q).all() and (sup.qd == v).all() and sup.counts["resync"] == 1
    assert sup.deviation(q).max() == 0.0  # the envelope restarts at the measured position
    assert not sup.resync([math.nan] * 6) and sup.brake_reason == "deviation"


def test_interventions_are_counted_per_tick():
    sup = SafetySupervisor(LIM, CFG, np.zeros(6))
    _ramp(sup, 0.5 * LIM.v_max, 10)
    assert (sup.ticks, sup.intervened) == (10, 0)
    sup.step(sup.q + 1.0, sup.qd)  # a jump: clamped
    assert (sup.ticks, sup.intervened) == (11, 1)
