"""Named unit conversions: the only place a factor 1000 between units is written.

Every function takes a float, a numpy array or None (None stays None: an unknown value stays unknown),
and divides or multiplies by the exact factor, so a value converted there and back differs by at
most one unit in the last place.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

T = TypeVar("T", float, np.ndarray, None)

MM_PER_M = 1000.0
MS_PER_S = 1000.0
MN_PER_N = 1000.0
UM_PER_MM = 1000.0


def mm_to_m(value_mm: T) -> T:
    """Millimetres (or mm/s, mm/s^2) to metres (m/s, m/s^2)."""
    return None if value_mm is None else value_mm / MM_PER_M


def m_to_mm(value_m: T) -> T:
    """Metres (or m/s, m/s^2) to millimetres (mm/s, mm/s^2)."""
    return None if value_m is None else value_m * MM_PER_M


def s_to_ms(value_s: T) -> T:
    """Seconds to milliseconds."""
    return None if value_s is None else value_s * MS_PER_S


def ms_to_s(value_ms: T) -> T:
    """Milliseconds to seconds."""
    return None if value_ms is None else value_ms / MS_PER_S


def n_to_mn(value_n: T) -> T:
    """Newtons to millinewtons."""
    return None if value_n is None else value_n * MN_PER_N


def um_to_mm(value_um: T) -> T:
    """Micrometres to millimetres."""
    return None if value_um is None else value_um / UM_PER_MM
