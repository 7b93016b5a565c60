"""The synthetic camera's read noise (vibro_sim.synth.sensor_noise): Gaussian with the sigma asked for, independent
from pixel to pixel and frame to frame, the same for the same seed.

Tolerances are sampling errors: over N draws the mean's standard error is sigma / sqrt(N), the variance's
sigma^2 sqrt(2 / N), a quantile's sqrt(p (1 - p) / N) / pdf(z_p), a correlation's 1 / sqrt(N); each bound is 5 of
them (a false failure once in ~3.5 million runs).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtri
from scipy.stats import norm

from vibro_sim.synth.sensor_noise import read_noise

SHAPE = (480, 160)          # one synthetic frame
FRAMES = 40
N = FRAMES * SHAPE[0] * SHAPE[1]   # 3.07 million draws


@pytest.fixture(scope="module")
def frames() -> np.ndarray:
    rng = np.random.default_rng(11)
    return np.stack([read_noise(rng, SHAPE, 2.5) for _ in range(FRAMES)])


def test_mean_and_sigma_are_what_was_asked(frames):
    sigma = 2.5
    assert frames.shape == (FRAMES, *SHAPE) and frames.dtype == np.float64
    assert abs(frames.mean()) < 5 * sigma / math.sqrt(N)
    assert abs(frames.var() / sigma ** 2 - 1.0) < 5 * math.sqrt(2.0 / N)


@pytest.mark.parametrize("p", [0.001, 0.023, 0.159, 0.5, 0.841, 0.977, 0.999])
def test_quantiles_are_the_normals(frames, p):
    z = np.quantile(frames / 2.5, p)
    se = math.sqrt(p * (1 - p) / N) / norm.pdf(ndtri(p))
    assert abs(z - ndtri(p)) < 5 * se + 2.0 / 65536 / norm.pdf(ndtri(p))   # + the table's bin width in z


def test_tails_are_a_normals_as_far_as_an_image_can_tell(frames):
    # beyond 3 sigma a normal puts 0.27 % of pixels; the table's cut-off at 4.33 sigma takes 1.5e-5 off that
    beyond = np.mean(np.abs(frames) > 3 * 2.5)
    expected = 2 * norm.sf(3.0)
    assert abs(beyond - expected) < 5 * math.sqrt(expected / N) + 1.5e-5
    assert np.abs(frames).max() / 2.5 < 4.34


def test_neighbours_and_successive_frames_are_independent(frames):
    z = frames / 2.5
    bound = 5 / math.sqrt(N)
    assert abs(np.mean(z[:, :, 1:] * z[:, :, :-1])) < bound * 1.01      # along a row
    assert abs(np.mean(z[:, 1:, :] * z[:, :-1, :])) < bound * 1.01      # down a column
    assert abs(np.mean(z[1:] * z[:-1])) < bound * 1.03                  # the same pixel, next frame


def test_same_seed_same_noise_and_sigma_scales_it():
    a = read_noise(np.random.default_rng(3), (4, 5), 1.0)
    b = read_noise(np.random.default_rng(3), (4, 5), 2.0)
    np.testing.assert_array_equal(2.0 * a, b)
    assert not np.array_equal(a, read_noise(np.random.default_rng(4), (4, 5), 1.0))
