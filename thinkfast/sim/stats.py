"""Statistics of block rates: one planner's rate, and two planners paired on the same throws.

Pure functions (no simulation here). A paired comparison of a planner ("other") with a reference
planner on the throws both ran is the 2x2 table

    both       reference and other blocked       (a)
    only_ref   reference blocked, other did not  (b)
    only_other other blocked, reference did not  (c)
    neither    neither blocked                   (d)

The difference in block rate, other minus reference, is ``(c - b) / n``. Its 95 % interval is
Newcombe's square-and-add interval for paired proportions (Newcombe 1998, Stat Med 17:2635,
method 10): the Wilson intervals of the two rates combined with the estimated correlation of
the pair. The test is McNemar's, exact: given the ``b + c`` discordant throws, ``b`` is binomial
with p = 1/2 when the planners block equally often.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from statistics import NormalDist

Z95 = 1.96  # two-sided 95 % normal quantile (the bench's Wilson intervals use it too)


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate k / n (NaNs when n is 0)."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(centre - half, 0.0), min(centre + half, 1.0))


def binomial_half_cdf(k: int, n: int) -> float:
    """P(X <= k) for X ~ Binomial(n, 1/2), exact (integer sums, one rounding at the end)."""
    if k < 0:
        return 0.0
    if k >= n:
        return 1.0
    term, total = 1, 1  # C(n, 0)
    for i in range(k):
        term = term * (n - i) // (i + 1)  # C(n, i + 1)
        total += term
    return total / (1 << n)


def mcnemar_exact(only_ref: int, only_other: int) -> tuple[float, float]:
    """Exact McNemar test on the discordant pairs.

    Args:
        only_ref: throws only the reference blocked (b).
        only_other: throws only the other planner blocked (c).

    Returns:
        ``(p_two_sided, p_reference_better)``: the two-sided p-value of "both block equally
        often" (twice the smaller binomial tail, at most 1; the same as
        ``scipy.stats.binomtest(b, b + c).pvalue``), and the one-sided p-value against the
        alternative "the reference blocks more often", P(X >= b) for X ~ Bin(b + c, 1/2).
        Both are 1 when there is no discordant throw.
    """
    if only_ref < 0 or only_other < 0:
        raise ValueError(f"counts must be >= 0, got {only_ref}, {only_other}")
    n = only_ref + only_other
    two = min(1.0, 2.0 * binomial_half_cdf(min(only_ref, only_other), n))
    return two, binomial_half_cdf(only_other, n)  # P(X >= b) = P(n - X <= c)


def paired_difference_ci(
    both: int, only_ref: int, only_other: int, neither: int, z: float = Z95
) -> tuple[float, float]:
    """Interval of the paired difference in rate, other minus reference (Newcombe method 10).

    With p1 = (a + c) / n (other) and p2 = (a + b) / n (reference), their Wilson intervals
    (l1, u1), (l2, u2) and the correlation estimate psi::

        lo = (p1 - p2) - sqrt((p1 - l1)^2 - 2 psi (p1 - l1)(u2 - p2) + (u2 - p2)^2)
        hi = (p1 - p2) + sqrt((p2 - l2)^2 - 2 psi (p2 - l2)(u1 - p1) + (u1 - p1)^2)

    where, with A = a d - b c and the product M of the four margins, psi is (A - n/2) / sqrt(M)
    when A > n/2, 0 when 0 <= A <= n/2, A / sqrt(M) when A < 0, and 0 when a margin is empty.

    Returns:
        (lo, hi), fractions in [-1, 1]; NaNs when there is no throw.
    """
    a, b, c, d = both, only_ref, only_other, neither
    n = a + b + c + d
    if n == 0:
        return (math.nan, math.nan)
    p1, p2 = (a + c) / n, (a + b) / n
    l1, u1 = wilson(a + c, n, z)
    l2, u2 = wilson(a + b, n, z)
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    big_a = a * d - b * c
    if margins == 0 or 0 <= big_a <= n / 2:
        psi = 0.0
    elif big_a > n / 2:
        psi = (big_a - n / 2) / math.sqrt(margins)
    else:
        psi = big_a / math.sqrt(margins)
    diff = p1 - p2
    lo = diff - math.sqrt(
        max((p1 - l1) ** 2 - 2 * psi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2, 0.0)
    )
    hi = diff + math.sqrt(
        max((p2 - l2) ** 2 - 2 * psi * (p2 - l2) * (u1 - p1) + (u1 - p1) ** 2, 0.0)
    )
    return (max(lo, -1.0), min(hi, 1.0))


def throws_needed(
    discordant: float, difference: float, power: float = 0.8, alpha: float = 0.05
) -> int:
    """Throws a paired comparison needs to resolve a difference (McNemar, normal approximation).

    Connor (1987): n = (z_(1-alpha/2) sqrt(f) + z_power sqrt(f - D^2))^2 / D^2, with ``f`` the
    expected share of discordant throws (only one planner blocked) and ``D`` the difference in
    rate to detect (fractions); exact-test sample sizes are a little larger.

    Returns:
        The number of throws (rounded up).
    """
    if not 0.0 < abs(difference) <= discordant <= 1.0:
        raise ValueError(
            f"need 0 < |difference| <= discordant <= 1, got {difference}, {discordant}"
        )
    za, zb = NormalDist().inv_cdf(1 - alpha / 2), NormalDist().inv_cdf(power)
    root = za * math.sqrt(discordant) + zb * math.sqrt(discordant - difference**2)
    return math.ceil(root**2 / difference**2)


def compare(reference: Sequence[bool], other: Sequence[bool], z: float = Z95) -> dict:
    """Paired comparison of two planners' outcomes on the same throws (aligned sequences).

    Returns:
        ``throws``, the four counts ``both``, ``only_reference``, ``only_other``, ``neither``,
        ``rate_reference``, ``rate_other``, ``difference`` (other minus reference, a fraction),
        ``ci95`` (:func:`paired_difference_ci`), ``p_exact`` (two-sided) and
        ``p_reference_better`` (one-sided), from :func:`mcnemar_exact`. Rates and the
        difference are NaN when there is no throw.
    """
    if len(reference) != len(other):
        raise ValueError(f"unpaired: {len(reference)} reference vs {len(other)} other outcomes")
    pairs = [(bool(r), bool(o)) for r, o in zip(reference, other, strict=True)]
    a = sum(r and o for r, o in pairs)
    b = sum(r and not o for r, o in pairs)
    c = sum(o and not r for r, o in pairs)
    n = len(pairs)
    d = n - a - b - c
    two, one = mcnemar_exact(b, c)
    lo, hi = paired_difference_ci(a, b, c, d, z)
    return {
        "throws": n,
        "both": a,
        "only_reference": b,
        "only_other": c,
        "neither": d,
        "rate_reference": (a + b) / n if n else math.nan,
        "rate_other": (a + c) / n if n else math.nan,
        "difference": (c - b) / n if n else math.nan,
        "ci95": [lo, hi],
        "p_exact": two,
        "p_reference_better": one,
    }
