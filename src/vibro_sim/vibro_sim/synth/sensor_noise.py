"""The synthetic camera's read noise: Gaussian, drawn from 16 random bits per pixel.

A frame of 160 x 480 pixels needs 76,800 normal draws; NumPy's ``Generator.normal`` takes ~0.7 ms for them, about
half of what synthesizing a frame costs. Here each pixel's noise is the standard normal quantile at the centre of
one of 2**16 equal-probability bins, the bin chosen by 16 random bits (``Generator.bytes``): ~0.15 ms a frame.

What that distribution is: a normal discretised in probability steps of 1/65536 and cut off at
|z| = 4.33 (the outermost bins' centres; a true normal exceeds that in 1.5e-5 of pixels), its table rescaled to
variance exactly 1, so that ``sigma`` is the noise's standard deviation. Written as 8-bit images (a few gray levels
of noise rounded to whole levels) nothing of the difference survives; tests/test_sensor_noise.py holds the moments,
the quantiles and the independence of neighbouring pixels and successive frames.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri

#: random bits per pixel: the table's 2**BITS bins
BITS = 16


def _unit_table() -> np.ndarray:
    """The 2**BITS standard normal bin-centre quantiles, rescaled to mean 0 and variance 1 exactly."""
    z = ndtri((np.arange(2 ** BITS) + 0.5) / 2 ** BITS)
    z -= z.mean()
    return z / np.sqrt(np.mean(z * z))


_UNIT = _unit_table()
_SCALED: dict[float, np.ndarray] = {}


def read_noise(rng: np.random.Generator, shape: tuple[int, ...], sigma: float) -> np.ndarray:
    """Zero-mean Gaussian noise of standard deviation ``sigma`` (the caller's unit: gray levels), float64 of
    ``shape``, drawn from ``rng`` (the same generator state gives the same noise, on any platform: the bits are
    read little-endian)."""
    table = _SCALED.get(sigma)
    if table is None:
        table = _SCALED[sigma] = _UNIT * float(sigma)
    n = int(np.prod(shape))
    index = np.frombuffer(rng.bytes(2 * n), dtype="<u2").reshape(shape)
    return table[index]
