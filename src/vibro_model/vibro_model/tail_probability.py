"""Upper-tail probabilities of the chi-square and F distributions (p-values of vibro's tests).

The same numbers as ``scipy.stats.chi2.sf`` / ``scipy.stats.f.sf`` (both evaluate these ``scipy.special``
functions), without importing ``scipy.stats``, which costs a node ~1.5 s of CPU at start-up. A statistic
below 0 (a nested non-linear fit that came out worse than the smaller one) has p = 1, as in scipy.stats.
"""

from __future__ import annotations

from scipy.special import chdtrc, fdtrc


def chi2_sf(chi2: float, dof: float) -> float:
    """P(X >= chi2) for X ~ chi-square with ``dof`` degrees of freedom."""
    return float(chdtrc(dof, max(float(chi2), 0.0)))


def f_sf(f: float, dof_num: float, dof_den: float) -> float:
    """P(X >= f) for X ~ F(``dof_num``, ``dof_den``)."""
    return float(fdtrc(dof_num, dof_den, max(float(f), 0.0)))
