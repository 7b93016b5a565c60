"""Issue 38: the replay (Eq. 18's D) drives the simulated cavity with the drive as it moved, not the take's average.

Ground truth: the synthetic rig's DriveChange kinematics (an amplitude step, a frequency drift), sampled as a
structure track with white noise; the identification's windowed drive (vibro_fit.drive) gives the envelope
(vibro_model.drive_envelope). Properties: the envelope's motion follows the true one where the average sine
cannot; its derivatives are exact; a stationary drive keeps the sine; the envelope survives the StructureMotion
message both ways; and the replay's D falls when the drive moved.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibro_fit import drive as drv
from vibro_fit.structure_fit import fit_structure
from vibro_model.drive_envelope import DriveEnvelope, EnvelopedDrive
from vibro_model.kinematics import DriveChange, StructureKinematics
from vibro_model.units import mm_to_m

FPS = 1000.0
A0_MM, F0_HZ = 1.41, 22.0
SIGMA_MM = 5e-4


def _case(n: int, seed: int, **change):
    """(truth kinematics in m, the global sine in m, the drive section) of a noisy structure track."""
    truth_mm = DriveChange(A0_MM, F0_HZ, 0.7, 0.05, **change)
    t = np.arange(n) / FPS
    y = np.asarray(truth_mm.position(t)) + np.random.default_rng(seed).normal(0.0, SIGMA_MM, n)
    fit = fit_structure(t, y)
    section = drv.fit_drive(t, y, fit).to_dict()
    sine = StructureKinematics(mm_to_m(abs(section["global"]["amplitude_mm"])), section["global"]["frequency_hz"],
                               section["global"]["phase_rad"], mm_to_m(fit.offset_mm))
    truth = DriveChange(mm_to_m(A0_MM), F0_HZ, 0.7, mm_to_m(0.05), **{k: v for k, v in change.items()})
    return truth, sine, section, fit


@pytest.mark.parametrize("change", [
    {"step_ratio": 0.10, "step_time_s": 1.5, "ramp_s": 0.3},       # the lab's amplitude step
    {"drift_hz_per_s": 0.02, "horizon_s": 10.0},                    # a slow frequency drift
])
def test_the_envelope_follows_the_drive_where_the_average_sine_cannot(change):
    truth, sine, section, fit = _case(4000, 1, **change)
    assert section["stationary"] is False            # the premise: the windowed drive saw it move
    env = DriveEnvelope.of_drive_section(section, mm_to_m(fit.offset_mm))
    moved = env.applied_to(sine)
    t = np.arange(200, 3800) / FPS                   # inside the windows' centres (held outside them)
    err_env = np.asarray(moved.position(t)) - np.asarray(truth.position(t))
    err_sine = np.asarray(sine.position(t)) - np.asarray(truth.position(t))
    v_env = np.asarray(moved.velocity(t)) - np.asarray(truth.velocity(t))
    v_sine = np.asarray(sine.velocity(t)) - np.asarray(truth.velocity(t))
    # the average sine misses by a share of the change; the envelope by what a linear interpolation between
    # window centres leaves of a ramp (a few % of the change) plus the windows' noise
    assert np.sqrt(np.mean(err_env ** 2)) < 0.2 * np.sqrt(np.mean(err_sine ** 2))
    assert np.sqrt(np.mean(v_env ** 2)) < 0.2 * np.sqrt(np.mean(v_sine ** 2))


def test_the_enveloped_motion_has_exact_derivatives_and_bounds():
    env = DriveEnvelope(t_s=(0.1, 0.5, 0.9, 1.3), amplitude_ratio=(1.0, 1.0, 1.1, 1.1),
                        phase_shift_rad=(0.0, 0.02, 0.05, 0.04), offset_shift_m=(0.0, 1e-5, -2e-5, 0.0))
    S = env.applied_to(StructureKinematics(1.4e-3, 22.0, 0.3, 1e-4, 0.05, 0.02, 0.5, -0.8))
    assert isinstance(S, EnvelopedDrive)
    t = np.linspace(-0.2, 1.6, 180_001)
    knots = np.asarray(env.t_s)
    inside = np.min(np.abs(t[:, None] - knots[None, :]), axis=1) > 1e-5   # a kink at each window centre
    h = 1e-6
    for order, (f, g) in enumerate(((S.position, S.velocity), (S.velocity, S.acceleration),
                                    (S.acceleration, S.jerk))):
        num = (np.asarray(f(t + h)) - np.asarray(f(t - h))) / (2 * h)
        exact = np.asarray(g(t))
        assert np.max(np.abs(num - exact)[inside]) < 1e-6 * np.max(np.abs(exact)), order
        assert np.max(np.abs(exact)) <= S.bound(order + 1)


def test_a_stationary_drive_keeps_the_sine():
    _, sine, section, fit = _case(4000, 2)
    assert section["stationary"] is True
    assert DriveEnvelope.of_drive_section(section, mm_to_m(fit.offset_mm)) is None
    assert DriveEnvelope.of_drive_section(None, 0.0) is None
    assert DriveEnvelope.of_drive_section({"stationary": None, "windows": []}, 0.0) is None


def test_a_damaged_envelope_is_refused_with_what_is_wrong():
    with pytest.raises(ValueError, match="increase"):
        DriveEnvelope(t_s=(0.0, 0.0), amplitude_ratio=(1.0, 1.0), phase_shift_rad=(0.0, 0.0), offset_shift_m=(0.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        DriveEnvelope(t_s=(0.0, 1.0), amplitude_ratio=(1.0, math.nan), phase_shift_rad=(0.0, 0.0),
                      offset_shift_m=(0.0, 0.0))
    with pytest.raises(ValueError, match="lengths"):
        DriveEnvelope(t_s=(0.0, 1.0), amplitude_ratio=(1.0,), phase_shift_rad=(0.0, 0.0), offset_shift_m=(0.0, 0.0))


def test_the_drive_travels_in_the_structure_message():
    """The graph's simulator and discrepancy nodes (and a bag's results) read the windowed drive from the final
    StructureMotion: the same envelope comes out as went in; a damaged field is refused by name."""
    from types import SimpleNamespace

    from vibro_model.errors import RecordingError
    from vibro_model.results import StructureMotion
    from vibro_ros.convert import drive_from_message, structure_from_message, structure_to_message

    _, sine, section, fit = _case(4000, 1, step_ratio=0.1, step_time_s=1.5, ramp_s=0.3)
    env = DriveEnvelope.of_drive_section(section, mm_to_m(fit.offset_mm))
    s = StructureMotion(amplitude_m=sine.amplitude_m, frequency_hz=sine.frequency_hz, phase_rad=sine.phase_rad,
                        offset_m=sine.offset_m)
    msg = structure_to_message(s, 4.0, 0, section)
    back = DriveEnvelope.of_drive_section(drive_from_message(msg), mm_to_m(fit.offset_mm))
    assert back is not None and len(back.t_s) == len(env.t_s)
    for a, b in zip((env.t_s, env.amplitude_ratio, env.phase_shift_rad, env.offset_shift_m),
                    (back.t_s, back.amplitude_ratio, back.phase_shift_rad, back.offset_shift_m)):
        assert np.allclose(a, b, rtol=1e-12, atol=1e-15)
    assert drive_from_message(structure_to_message(s, 4.0, 0)) is None
    assert drive_from_message(SimpleNamespace()) is None          # a bag recorded before the field existed
    assert structure_from_message(msg).amplitude_m == pytest.approx(s.amplitude_m)
    with pytest.raises(RecordingError, match="drive_json"):
        drive_from_message(SimpleNamespace(drive_json="{broken"))
    with pytest.raises(RecordingError, match="drive_json"):
        drive_from_message(SimpleNamespace(drive_json="[1, 2]"))


def test_one_time_at_a_time_is_the_same_motion():
    """The simulator asks one time at a time (a scalar path without arrays): the same values as the array path,
    inside the windows, between them and outside, for every derivative."""
    env = DriveEnvelope(t_s=(0.1, 0.5, 0.9, 1.3), amplitude_ratio=(1.0, 1.0, 1.1, 1.1),
                        phase_shift_rad=(0.0, 0.02, 0.05, 0.04), offset_shift_m=(0.0, 1e-5, -2e-5, 0.0))
    S = env.applied_to(StructureKinematics(1.4e-3, 22.0, 0.3, 1e-4, 0.05, 0.02, 0.5, -0.8))
    t = np.array([-0.3, 0.1, 0.2345, 0.5, 0.77, 1.3, 1.9])
    for f in (S.position, S.velocity, S.acceleration, S.jerk):
        arr = np.asarray(f(t))
        one = np.array([f(float(x)) for x in t])
        assert np.allclose(one, arr, rtol=1e-12, atol=1e-15)


def test_demodulating_an_enveloped_track_gives_the_global_drive_with_its_harmonics():
    # Y(t) = B + dB(t) + r(t) A [sin(th) + h2 sin(2 th + p2) + ...], th = w t + phi + dphi(t): taking dB off,
    # dividing by r and moving each sample to t + dphi / w gives the global sine (harmonics included) exactly,
    # which is what the discrepancy analysis fits its harmonics on (a drive that moved is not a harmonic)
    env = DriveEnvelope(t_s=(0.1, 0.5, 0.9, 1.3), amplitude_ratio=(1.0, 1.0, 1.1, 1.1),
                        phase_shift_rad=(0.0, 0.2, 0.5, 0.4), offset_shift_m=(0.0, 1e-5, -2e-5, 0.0))
    glob = StructureKinematics(1.4e-3, 22.0, 0.3, 1e-4, 0.05, 0.02, 0.5, -0.8)
    t = np.linspace(0.0, 1.4, 1401)
    y = np.asarray(env.applied_to(glob).position(t))
    t2, y2 = env.demodulated(t, y, glob.offset_m, glob.frequency_hz)
    assert np.max(np.abs(y2 - np.asarray(glob.position(t2)))) < 1e-12
    assert np.max(np.abs(t2 - t)) == pytest.approx(0.5 / (2 * math.pi * 22.0), rel=1e-9)   # the largest shift
