"""The cores of the cross-checks on constructed inputs: the phase-step scan (vibro_fit.cross_checks.step_scan,
time_base_step) and the plausibility bounds (vibro_fit.plausibility), with noise drawn at known sigma."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from vibro_fit.cross_checks import STEP_Z, step_scan, time_base_step
from vibro_fit.plausibility import cor_outside_bounds, negative_friction
from vibro_fit.structure_fit import fit_structure
from vibro_model.results import Flight, Impact

FPS, F_HZ, A_MM, NOISE_MM = 1000.0, 22.0, 1.41, 0.002
M_KG = 1.82e-4


def _structure_track(n: int, drop: int | None, seed: int, drift_hz_per_s: float = 0.0):
    """Frame times k / fps; frame k >= drop shows the sine one frame period later (a frame lost before it); the
    drive's frequency F_HZ + drift_hz_per_s t (phase 2 pi (F_HZ t + drift t^2 / 2))."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    t_true = (k + (k >= drop if drop is not None else 0)) / FPS
    phase = 2 * math.pi * (F_HZ * t_true + 0.5 * drift_hz_per_s * t_true ** 2)
    y = A_MM * np.sin(phase + 0.3) + 0.1 + rng.normal(0.0, NOISE_MM, n)
    t = k / FPS
    track = SimpleNamespace(t_s=t, structure_mm=y, frame=k, good=np.ones(n, bool))
    return track, fit_structure(t, y)


@pytest.mark.parametrize("drop", [37, 150, 911])
def test_step_scan_locates_a_lost_frame_to_the_frame(drop):
    track, fit = _structure_track(1200, drop, seed=drop)
    finding = time_base_step(track, fit, FPS)
    assert finding is not None and finding.frame == drop and finding.refuses
    # one frame period within the linearisation's second-order bias w tau / 2 and 5 sigma of the estimate
    ev = finding.evidence
    assert ev["step_frames"] == pytest.approx(1.0, abs=math.pi * F_HZ / FPS + 5 * ev["step_std_s"] * FPS)


def test_step_scan_raises_no_alarm_on_noise():
    # 40 clean tracks: the largest step's z stays below the look-elsewhere level + STEP_Z (a Gaussian maximum
    # over N positions exceeds sqrt(2 ln N) + 6 with probability ~ e^-18 per track) and no finding is made
    for seed in range(40):
        track, fit = _structure_track(600, None, seed)
        scan = step_scan(track.t_s, track.structure_mm, fit)
        assert scan["z"] < scan["look_elsewhere_z"] + STEP_Z
        assert time_base_step(track, fit, FPS) is None


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_drive_whose_frequency_drifts_is_no_lost_frame(seed):
    # 0.02 Hz/s over 3 s (the synthetic rig's drive_change): the phase bends by pi 0.02 9 = 0.57 rad, smoothly;
    # the scan once took a 0.79-frame step of it for a frame lost at 2.4 s and refused the take
    track, fit = _structure_track(3000, None, seed, drift_hz_per_s=0.02)
    assert time_base_step(track, fit, FPS) is None


@pytest.mark.parametrize("drop", [700, 2100])
def test_a_lost_frame_is_found_on_a_drifting_drive_too(drop):
    track, fit = _structure_track(3000, drop, seed=drop, drift_hz_per_s=0.02)
    finding = time_base_step(track, fit, FPS)
    assert finding is not None and finding.frame == drop and finding.refuses


def _impact(k: int, plate: str, cor: float, sd: float) -> Impact:
    return Impact(index=k, t_s=0.01 * k, plate=plate, cor=cor, cor_std=sd, v_ball_before_mps=0.5,
                  v_ball_after_mps=-0.35, v_structure_mps=0.0)


def test_cor_bounds_flag_only_what_leaves_0_1_beyond_sigma():
    rng = np.random.default_rng(1)
    # CORs near 1 with honest sigmas (a hard steel ball): inside [0, 1] up to their scatter -> no alarm
    near_one = [_impact(k, "top" if k % 2 else "bottom", min(0.985 + rng.normal(0, 0.01), 1.02), 0.01)
                for k in range(20)]
    assert cor_outside_bounds(near_one) is None
    # a plate's CORs at 1.15 +- 0.02: far above 1 per impact and on average
    high = [_impact(k, "top", 1.15 + rng.normal(0, 0.02), 0.02) for k in range(6)]
    out = cor_outside_bounds(high)
    assert out is not None and out["plates"]["top"][0] == pytest.approx(1.15, abs=3 * 0.02 / math.sqrt(6) + 0.01)
    assert len(out["impacts"]) == 6


def _flight(k: int, direction: str, force_n: float, sd_n: float) -> Flight:
    return Flight(index=k, t_first_frame_s=0.0, t_last_frame_s=0.01, a_mps2=-4.9, b_mps=0.0, c_m=0.0,
                  direction=direction, friction_n=force_n, friction_std_n=sd_n, rms_residual_m=1e-6, n_points=20,
                  free=True)


def test_negative_friction_is_energy_gain_not_a_tilt():
    sd = 2e-6
    rng = np.random.default_rng(2)
    # Eq. 17 (F = m (2a + g), + up). A gravity tilt adds the same upward force to both directions: no alarm.
    tilt = M_KG * 9.81 * (1 - math.cos(math.radians(30)))
    flights = [_flight(k, "up" if k % 2 else "down", tilt + rng.normal(0, sd), sd) for k in range(20)]
    assert negative_friction(flights, M_KG) is None
    # a real friction opposes the motion (down on up-flights, up on down-flights): no alarm
    mu = 1.5e-4
    flights = [_flight(k, "up" if k % 2 else "down", (-mu if k % 2 else mu) + rng.normal(0, sd), sd)
               for k in range(20)]
    assert negative_friction(flights, M_KG) is None
    # a force along the motion in both directions feeds energy in: refused, its size measured
    flights = [_flight(k, "up" if k % 2 else "down", (mu if k % 2 else -mu) + rng.normal(0, sd), sd)
               for k in range(20)]
    out = negative_friction(flights, M_KG)
    assert out is not None and out["dissipative_n"] == pytest.approx(-mu, abs=5 * out["std_n"])
