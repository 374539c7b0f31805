"""Chi-square gate limits equal scipy.stats' quantiles without importing scipy.stats."""

from __future__ import annotations

import subprocess
import sys

import pytest

from thinkfast.estimate.chi2 import chi2_limit


@pytest.mark.parametrize("alpha", [1e-6, 1e-3, 0.01, 0.05, 0.5])
@pytest.mark.parametrize("dof", [1, 3, 6, 30])
def test_the_limit_is_the_upper_quantile(alpha, dof):
    from scipy.stats import chi2

    assert chi2_limit(alpha, dof) == chi2.isf(alpha, dof)
    assert chi2.sf(chi2_limit(alpha, dof), dof) == pytest.approx(alpha, rel=1e-9)


def test_the_daemons_planning_core_does_not_import_scipy_stats():
    """scipy.stats takes seconds to import: the daemon's start-up must not pay it."""
    code = "import sys, thinkfast.daemon.service; print('scipy.stats' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
