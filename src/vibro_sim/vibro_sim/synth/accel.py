"""Accelerometer signals (m/s^2) of the upper and lower plates at 50 kHz.

Each plate sees the structure's rigid acceleration Y_s''(t) plus, after each impact at
t_i with impulse J = m (v+ - v-) (N s), a decaying multi-mode burst

    sum_k g_p J w_k / m_k  sin(w_k (t - t_i)) exp(-zeta_k w_k (t - t_i)),   t > t_i

(the impulse response of modes of modal mass m_k), with g_p = 1 on the plate that was
hit and ``cross_gain`` on the other, plus Gaussian noise. The DAQ clock runs ahead of
the camera clock by ``clock_offset_s`` at camera time 0 and fast by ``clock_rate_ppm``
(its crystal's error):

    t_daq = t_camera + clock_offset_s + clock_rate_ppm * 1e-6 * t_camera

so the sample written with time t (every 1 / rate_hz on the DAQ's clock) was taken at
camera time (t - clock_offset_s) / (1 + clock_rate_ppm * 1e-6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# (frequency Hz, damping ratio, modal mass kg): plausible plate/rod modes of the rig.
MODES = ((2150.0, 0.012, 0.25), (4730.0, 0.010, 0.35), (8310.0, 0.008, 0.5), (13500.0, 0.006, 0.8))
CROSS_GAIN = 0.3
BURST_DECAY_TAUS = 8.0  # burst truncated after this many decay times of its slowest mode


@dataclass
class AccelSignals:
    t_daq_s: np.ndarray
    upper_ms2: np.ndarray
    lower_ms2: np.ndarray


@dataclass(frozen=True, kw_only=True)
class DaqSettings:
    """The accelerometer DAQ: sample rate (Hz, on its own clock), noise std (m/s^2), its clock's lead on the
    camera clock at camera time 0 (s) and how much faster its clock runs than the camera's (ppm)."""

    rate_hz: float
    noise_mps2: float
    clock_offset_s: float
    clock_rate_ppm: float = 0.0

    def daq_s(self, t_camera_s):
        """DAQ-clock times (s) of camera times ``t_camera_s`` (s)."""
        return t_camera_s + self.clock_offset_s + 1e-6 * self.clock_rate_ppm * t_camera_s

    def camera_s(self, t_daq_s):
        """Camera times (s) of DAQ-clock times ``t_daq_s`` (s): the inverse of :meth:`daq_s`."""
        return (t_daq_s - self.clock_offset_s) / (1.0 + 1e-6 * self.clock_rate_ppm)


def make_accel(structure, impacts, mass_kg: float, window_s: tuple[float, float], daq: DaqSettings,
               rng: np.random.Generator) -> AccelSignals:
    """Samples on the DAQ clock covering the camera window ``window_s`` = (first, last) camera time (s), each the
    rig's acceleration at the camera time it was taken (:class:`DaqSettings`: offset and rate of the DAQ clock)."""
    t_first_s, t_last_s = window_s
    rate_hz, noise_mps2 = daq.rate_hz, daq.noise_mps2
    n0 = int(math.ceil(daq.daq_s(t_first_s) * rate_hz))
    n1 = int(math.floor(daq.daq_s(t_last_s) * rate_hz))
    t_daq = np.arange(n0, n1 + 1) / rate_hz
    t_cam = daq.camera_s(t_daq)
    base = np.asarray(structure.acceleration(t_cam), dtype=float)
    upper = base.copy()
    lower = base.copy()
    span = max(BURST_DECAY_TAUS / (z * 2 * math.pi * f) for f, z, _ in MODES)
    for imp in impacts:
        J = mass_kg * (imp.v_ball_after_mps - imp.v_ball_before_mps)
        i0 = int(np.searchsorted(t_cam, imp.t_s, side="right"))
        i1 = int(np.searchsorted(t_cam, imp.t_s + span, side="right"))
        if i1 <= i0:
            continue
        tau = t_cam[i0:i1] - imp.t_s
        burst = np.zeros_like(tau)
        for f, z, mk in MODES:
            w = 2 * math.pi * f
            burst += (abs(J) * w / mk) * np.sin(w * tau) * np.exp(-z * w * tau)
        # sign: the hit plate is pushed away from the ball (top: up, bottom: down)
        sign = 1.0 if imp.plate == "top" else -1.0
        hit, other = (upper, lower) if imp.plate == "top" else (lower, upper)
        hit[i0:i1] += sign * burst
        other[i0:i1] += sign * CROSS_GAIN * burst
    if noise_mps2 > 0:
        upper += rng.normal(0.0, noise_mps2, upper.shape)
        lower += rng.normal(0.0, noise_mps2, lower.shape)
    return AccelSignals(t_daq, upper, lower)
