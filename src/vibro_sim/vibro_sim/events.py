"""Find the first zero of a smooth function without stepping past it.

``first_root(f, ta, tb, m2, step)`` scans [ta, tb] for the first t where f(t) <= 0,
given f(ta) > 0 and a bound m2 >= |f''| on the interval. On a grid interval
[t_k, t_k+1] of width h, f >= min(f_k, f_k+1) - m2 h^2 / 8 (linear interpolation
error), so an interval whose bound stays positive cannot hold a zero; an interval whose
ends have opposite signs is refined by Brent's method to ``xtol`` seconds; an interval
that is positive at both ends but not provably so inside (a possible double crossing,
i.e. a grazing contact) is split 16-fold recursively down to ``min_step``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.optimize import brentq

CHUNK = 256


def first_root(f: Callable, ta: float, tb: float, m2: float, step: float,
               xtol: float = 1e-12, min_step: float = 1e-10, touch_tol: float = 1e-13) -> float | None:
    """First t in (ta, tb] with f(t) <= 0, or None. ``f`` must accept numpy arrays."""
    t = ta
    while t < tb:
        n = int(min(CHUNK, np.ceil((tb - t) / step)))
        if n <= 0:
            break
        grid = t + step * np.arange(n + 1)
        grid[-1] = min(grid[-1], tb)
        grid = grid[grid <= tb]
        if grid.size < 2:
            grid = np.array([t, tb])
        vals = np.asarray(f(grid), dtype=float)
        widths = np.diff(grid)
        crossing = vals[1:] <= 0.0
        ambiguous = np.minimum(vals[:-1], vals[1:]) <= m2 * widths ** 2 / 8.0
        flagged = np.flatnonzero(crossing | ambiguous)
        for k in flagged:
            a, b = grid[k], grid[k + 1]
            if vals[k] <= 0.0:  # only possible at the very start; caller guarantees > 0
                return float(a)
            if crossing[k]:
                if vals[k + 1] == 0.0:
                    return float(b)
                return float(brentq(f, a, b, xtol=xtol, rtol=4 * np.finfo(float).eps))
            sub = b - a
            if sub / 16.0 >= min_step:
                r = first_root(f, a, b, m2, sub / 16.0, xtol=xtol, min_step=min_step, touch_tol=touch_tol)
                if r is not None:
                    return r
            else:
                # Unresolvable near-touch: call it a contact if f is within touch_tol of 0.
                mid = np.linspace(a, b, 9)
                fm = np.asarray(f(mid), dtype=float)
                j = int(np.argmin(fm))
                if fm[j] <= touch_tol:
                    return float(mid[j])
        t = float(grid[-1])
    return None
