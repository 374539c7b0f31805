"""Paired planner statistics: exact McNemar p-values, Newcombe's paired interval, pairing rules."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom, binomtest

from thinkfast.sim.lockstep import Outcome
from thinkfast.sim.paired import format_paired, paired_summary
from thinkfast.sim.stats import (
    binomial_half_cdf,
    compare,
    mcnemar_exact,
    paired_difference_ci,
    throws_needed,
    wilson,
)


def test_mcnemar_exact_hand_computed_cases():
    """b=0, c=5: two-sided 2 * (1/2)^5 = 0.0625; one-sided 'reference better' P(X >= 0) = 1,
    and with the roles swapped (1/2)^5 = 0.03125; equal discordant counts give p = 1."""
    assert mcnemar_exact(0, 5) == (0.0625, 1.0)
    assert mcnemar_exact(5, 0) == (0.0625, 0.03125)
    for k in (0, 1, 3, 10, 250):
        assert mcnemar_exact(k, k)[0] == 1.0
    # b=1, c=9: 2 * (1 + 10) / 1024 = 0.021484375; P(X >= 1) = 1 - 1/1024
    assert mcnemar_exact(1, 9) == (22 / 1024, 1023 / 1024)
    with pytest.raises(ValueError):
        mcnemar_exact(-1, 3)


def test_mcnemar_exact_equals_scipy_binomtest():
    """Two-sided and one-sided ('greater') exact binomial tests of b out of b + c at p = 1/2."""
    cases = [(b, c) for b in range(0, 25, 3) for c in range(0, 25, 4)] + [(130, 170), (612, 555)]
    for b, c in cases:
        if b + c == 0:
            continue
        two, one = mcnemar_exact(b, c)
        assert two == pytest.approx(binomtest(b, b + c).pvalue, rel=1e-9, abs=1e-300)
        ref = binomtest(b, b + c, alternative="greater").pvalue
        assert one == pytest.approx(ref, rel=1e-9, abs=1e-300)


def test_binomial_tail_is_exact_far_into_the_tail():
    for n, k in [(0, 0), (1, 0), (40, 3), (2000, 900), (2000, 1000), (3000, 1400)]:
        assert binomial_half_cdf(k, n) == pytest.approx(binom.cdf(k, n, 0.5), rel=1e-9)
    assert binomial_half_cdf(-1, 5) == 0.0 and binomial_half_cdf(5, 5) == 1.0


def test_newcombe_interval_hand_computed_when_the_correlation_term_vanishes():
    """Bentur et al. table (both 1, only-reference 7, only-other 1, neither 12, n = 21):
    A = 1*12 - 7*1 = 5 <= n/2, so psi = 0 and the interval is square-and-add of the two Wilson
    intervals: other 2/21 in [0.026518, 0.289146], reference 8/21 in [0.207508, 0.591217];
    lo = -0.285714 - sqrt(0.068720^2 + 0.210265^2) = -0.506924,
    hi = -0.285714 + sqrt(0.173444^2 + 0.193908^2) = -0.025554."""
    lo, hi = paired_difference_ci(1, 7, 1, 12)
    assert lo == pytest.approx(-0.506924, abs=2e-6) and hi == pytest.approx(-0.025554, abs=2e-6)
    assert wilson(2, 21) == pytest.approx((0.026518, 0.289146), abs=1e-6)


def test_newcombe_interval_is_antisymmetric_contains_the_estimate_and_stays_in_range():
    rng = np.random.default_rng(11)
    for _ in range(300):
        a, b, c, d = (int(x) for x in rng.integers(0, 30, 4))
        n = a + b + c + d
        if n == 0:
            continue
        lo, hi = paired_difference_ci(a, b, c, d)
        lo2, hi2 = paired_difference_ci(a, c, b, d)  # roles swapped
        assert (lo2, hi2) == pytest.approx((-hi, -lo), abs=1e-12)
        assert -1.0 <= lo <= (c - b) / n <= hi <= 1.0
    assert all(math.isnan(x) for x in paired_difference_ci(0, 0, 0, 0))


def test_newcombe_interval_approaches_the_wald_interval_for_many_throws():
    """n = 100,000: Wald half-width 1.96 * sqrt((b + c) - (b - c)^2 / n) / n."""
    a, b, c, d = 60_000, 3_000, 2_500, 34_500
    n = a + b + c + d
    lo, hi = paired_difference_ci(a, b, c, d)
    est = (c - b) / n
    half = 1.96 * math.sqrt((b + c) - (b - c) ** 2 / n) / n
    assert (est - lo) == pytest.approx(half, rel=0.02) and (hi - est) == pytest.approx(
        half, rel=0.02
    )


def test_newcombe_interval_covers_the_true_difference_about_95_percent():
    """2,000 seeded 2x2 tables of 100 correlated pairs (true difference +3 points); ignoring the
    pairing (psi = 0) would cover 99.9 % of them here, far above the upper bound."""
    rng = np.random.default_rng(7)
    probs = [0.55, 0.05, 0.08, 0.32]  # both, only reference, only other, neither
    true = probs[2] - probs[1]
    tables = rng.multinomial(100, probs, size=2000)
    cover = np.mean([lo <= true <= hi for lo, hi in (paired_difference_ci(*t) for t in tables)])
    assert 0.93 <= cover <= 0.975, cover


def test_throws_needed_matches_hand_computed_sizes_and_simulated_power():
    """10 points with 20 % discordant: (1.95996 sqrt(0.2) + 0.84162 sqrt(0.19))^2 / 0.01
    = (0.876523 + 0.366855)^2 / 0.01 = 154.60; 2 points with 6 % discordant:
    (0.480091 + 0.205466)^2 / 0.0004 = 1174.97.
    At the 155 throws of the first, the exact test rejects in about 80 % of seeded draws."""
    assert throws_needed(0.2, 0.1) == 155 and throws_needed(0.2, -0.1) == 155
    assert throws_needed(0.06, 0.02) == 1175
    rng = np.random.default_rng(3)
    tables = rng.multinomial(155, [0.5, 0.05, 0.15, 0.3], size=1000)  # f = 0.2, D = +0.1
    power = np.mean([mcnemar_exact(int(t[1]), int(t[2]))[0] < 0.05 for t in tables])
    assert 0.72 <= power <= 0.86, power
    with pytest.raises(ValueError):
        throws_needed(0.05, 0.1)


def test_compare_counts_the_four_cells_and_refuses_unpaired_input():
    ref = [True, True, False, False, True, False, True]
    oth = [True, False, True, False, True, True, True]
    e = compare(ref, oth)
    assert (e["both"], e["only_reference"], e["only_other"], e["neither"]) == (3, 1, 2, 1)
    assert e["throws"] == 7 and e["difference"] == pytest.approx(1 / 7)
    assert (e["rate_reference"], e["rate_other"]) == pytest.approx((4 / 7, 5 / 7))
    assert (e["p_exact"], e["p_reference_better"]) == mcnemar_exact(1, 2)
    with pytest.raises(ValueError):
        compare([True], [True, False])


def _row(tid: str, planner: str, blocked: bool, flight: float, kind: str = "still") -> Outcome:
    return Outcome(
        tid, planner, blocked, "blocked" if blocked else "late", 0.0, flight, 0.0, 1.0, 3,
        True, 0.15, kind,
    )  # fmt: skip


def test_paired_summary_pairs_released_throws_by_id_and_splits_by_kind_and_flight_time():
    """Any planner names; feints and throws only one planner ran are left out; a repeated id
    pairs occurrence by occurrence."""
    plan = [  # id, flight, kind, blocked by ref / by "naive-paper"
        ("t0", 0.45, "still", True, True),
        ("t1", 0.55, "windup", True, False),
        ("t2", 0.65, "windup", False, True),
        ("t2", 0.75, "still", False, False),  # the same id again (a throw set may repeat one)
        ("f0", 0.50, "feint", False, False),
    ]
    rows = []
    for tid, fl, kind, r, o in plan:
        rows += [_row(tid, "ref", r, fl, kind), _row(tid, "naive-paper", o, fl, kind)]
    rows.append(_row("t9", "ref", True, 0.5))  # only the reference ran it
    s = paired_summary(rows, ["ref", "naive-paper"], "ref", (0.4, 0.5, 0.6, 0.7, 0.8))
    e = s["planners"]["naive-paper"]
    assert s["reference"] == "ref" and list(s["planners"]) == ["naive-paper"]
    o = e["overall"]
    assert (o["throws"], o["both"], o["only_reference"], o["only_other"], o["neither"]) == (
        4, 1, 1, 1, 1,
    )  # fmt: skip
    assert set(e["by_kind"]) == {"still", "windup"}
    assert (e["by_kind"]["windup"]["only_reference"], e["by_kind"]["windup"]["only_other"]) == (
        1, 1,
    )  # fmt: skip
    assert [x["throws"] for x in e["by_flight_time"]] == [1, 1, 1, 1]
    assert e["by_flight_time"][3]["neither"] == 1  # 0.75 s: the second "t2"
    text = "\n".join(format_paired(s))
    assert "paired vs ref" in text and "naive-paper windup" in text
    with pytest.raises(ValueError):
        paired_summary(rows, ["naive-paper"], "ref", (0.4, 0.8))


def test_wilson_interval_equals_scipys_at_the_exact_quantile():
    """scipy.stats.binomtest(...).proportion_ci(method='wilson') uses the exact 97.5 % point;
    the default z = 1.96 stays within 1e-4 of it."""
    from statistics import NormalDist

    z = NormalDist().inv_cdf(0.975)
    for k, n in [(0, 1), (0, 10), (3, 10), (10, 10), (74, 100), (412, 1000), (999, 1000)]:
        ref = binomtest(k, n).proportion_ci(0.95, method="wilson")
        lo, hi = wilson(k, n, z)
        assert lo == pytest.approx(ref.low, abs=1e-12) and hi == pytest.approx(ref.high, abs=1e-12)
        lo, hi = wilson(k, n)
        assert abs(lo - ref.low) < 1e-4 and abs(hi - ref.high) < 1e-4
