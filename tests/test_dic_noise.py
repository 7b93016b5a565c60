"""Noise split of a displacement series (vibro_dic.noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibro_dic.noise import cramer_rao_px, split_noise
from vibro_model.errors import RecordingError


def test_split_separates_slow_drift_from_white_noise() -> None:
    fps, n = 1000.0, 4000
    rng = np.random.default_rng(0)
    a, sigma = 2e-3, 1e-3  # mm: 5 Hz "camera motion" and white image noise
    t = np.arange(n) / fps
    x = a * np.sin(2 * np.pi * 5.0 * t) + sigma * rng.standard_normal(n)
    s = split_noise(x, fps, split_hz=50.0)
    # white noise spreads evenly over 0..500 Hz: ~10 % of its variance falls below 50 Hz
    # (a little less: the zero-phase Butterworth-4 response squared is not a brick wall).
    # 5 Hz passes the low-pass unattenuated. Std estimates from n = 4000 samples scatter by
    # 1/sqrt(2n) ~ 1.1 %: tolerances of 5 % are > 4 sigma.
    assert s["low_std_mm"] == pytest.approx(math.sqrt(a**2 / 2 + 0.1 * sigma**2), rel=0.05)
    assert s["high_std_mm"] == pytest.approx(sigma * math.sqrt(0.9), rel=0.05)
    assert s["std_mm"] == pytest.approx(math.sqrt(a**2 / 2 + sigma**2), rel=0.05)


def test_lost_frames_are_left_out() -> None:
    rng = np.random.default_rng(1)
    x = 1e-3 * rng.standard_normal(500)
    y = x.copy()
    y[100:110] = np.nan
    assert split_noise(y, 1000.0)["n_used"] == 490
    assert split_noise(y, 1000.0)["std_mm"] == pytest.approx(np.std(np.delete(x, range(100, 110))), rel=1e-9)


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(RecordingError, match="split"):
        split_noise(np.zeros(100), 1000.0, split_hz=600.0)
    with pytest.raises(RecordingError, match="at least"):
        split_noise(np.full(100, np.nan), 1000.0)


def test_cramer_rao_bound_formula() -> None:
    # sqrt(2) sigma / sqrt(sum grad^2): 961 px of unit gradient and sigma 2 -> 2 sqrt(2) / 31
    assert cramer_rao_px(961.0, 2.0) == pytest.approx(2.0 * math.sqrt(2.0) / 31.0)
