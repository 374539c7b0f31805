"""Chi-square gate limits: the value a chi-square variable with ``dof`` degrees of freedom
passes with probability ``alpha`` (``scipy.stats.chi2.isf``, from ``scipy.special`` directly:
importing ``scipy.stats`` costs the daemon seconds at start-up)."""

from __future__ import annotations

import functools

from scipy.special import chdtri


@functools.lru_cache(maxsize=64)
def chi2_limit(alpha: float, dof: int) -> float:
    """Upper ``alpha`` quantile of the chi-square distribution.

    Args:
        alpha: probability of exceeding the limit, in (0, 1).
        dof: degrees of freedom, >= 1.

    Returns:
        The limit ``x`` with ``P(chi2_dof > x) = alpha``.
    """
    return float(chdtri(dof, alpha))
