"""Issue 38 item 2: a correction may not silently make the answer worse.

The final model re-measures every impact against its one structure fit. Where the drive's amplitude or phase
moved during the take, that fit misses the structure's velocity at the impact, and the re-measured COR is biased
where the first pass (a structure fit local to each impact) is not. :func:`structure_misfit` measures that local
miss from the measured structure track; :func:`with_local_structure` measures the impact with the local
structure velocity where the miss moves the COR beyond noise and floor. Checked here against the analytic miss
of a sine whose amplitude steps by 10 %.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.reidentify import (
    COR_SUPPORT_FLOOR,
    cor_shift_of_misfit,
    structure_misfit,
    with_local_structure,
)
from vibro_model.kinematics import StructureKinematics
from vibro_model.results import Impact, StructureMotion

F_HZ = 22.0
A_M = 1.4e-3
PHASE = 0.4
FPS = 1000.0
NOISE_M = 2e-7  # DIC structure noise, a few tenths of a um


def _measured(step_at_s: float, ratio: float, seed: int = 1) -> Measured:
    """A 4 s structure track whose amplitude is A before ``step_at_s`` and A (1 + ratio) after, with DIC noise."""
    t = np.arange(int(4.0 * FPS)) / FPS
    amp = np.where(t < step_at_s, A_M, A_M * (1 + ratio))
    y = amp * np.sin(2 * math.pi * F_HZ * t + PHASE) + np.random.default_rng(seed).normal(0, NOISE_M, t.size)
    sine = StructureMotion(amplitude_m=A_M, frequency_hz=F_HZ, phase_rad=PHASE, offset_m=0.0)
    return Measured(structure=sine, flights=[], impacts=[], t_s=t, ball_m=np.zeros_like(t), structure_m=y,
                    mass_kg=1.8e-4, free_play_m=1.3e-3)


def test_the_misfit_is_the_velocity_the_model_misses_and_zero_where_it_follows() -> None:
    meas = _measured(step_at_s=2.0, ratio=0.10)
    model = StructureKinematics(A_M, F_HZ, PHASE)  # follows the first half exactly, misses the second by 10 %
    w = 2 * math.pi * F_HZ
    for t in (0.5123, 1.2, 2.6, 3.4567):
        m = structure_misfit(meas, model, t)
        dv, dv_std = m.dv_mps, m.total_std_mps
        expected = (0.10 * A_M * w * math.cos(w * t + PHASE)) if t > 2.0 + 1 / F_HZ else 0.0
        # the noise of the local fit over half a period either side (~45 frames): w sigma_y sqrt(2/N) ~ 6e-6 m/s
        # for a plain sine, ~2.5x that with the ramp terms (a1, b1: the velocity takes b1 too)
        assert dv_std < 2.5e-5
        assert abs(dv - expected) < 5 * dv_std + 1e-9, (t, dv, expected, dv_std)


def test_a_ten_percent_step_moves_the_cor_beyond_the_floor_and_noise_does_not() -> None:
    meas = _measured(step_at_s=2.0, ratio=0.10)
    model = StructureKinematics(A_M, F_HZ, PHASE)
    w = 2 * math.pi * F_HZ
    # an impact at the structure's fastest point after the step: v_s off by 0.1 A w = 19 mm/s
    t = (2 * math.pi * 60 - PHASE) / w
    imp = Impact(index=0, t_s=t, plate="bottom", cor=0.7, cor_std=1e-4, v_ball_before_mps=-0.5,
                 v_ball_after_mps=0.37, v_structure_mps=0.02, flight_before=0, flight_after=1)
    dv = structure_misfit(meas, model, t).dv_mps
    shift = cor_shift_of_misfit(imp, dv)
    # de/dv_s = (v_b - v_a) / (v_b - v_s)^2 = -0.87 / 0.27 = -3.2 per m/s: ~0.06 for 19 mm/s
    assert abs(shift) > 100 * COR_SUPPORT_FLOOR
    assert math.isclose(dv, 0.10 * A_M * w, rel_tol=0.05)
    # before the step the same impact geometry shows only noise, far under the floor
    t0 = (2 * math.pi * 20 - PHASE) / w
    dv0 = structure_misfit(meas, model, t0).dv_mps
    assert abs(cor_shift_of_misfit(imp, dv0)) < 0.1 * COR_SUPPORT_FLOOR


def test_an_impact_where_the_model_misses_the_drive_takes_the_local_structure_velocity() -> None:
    meas = _measured(step_at_s=2.0, ratio=0.10)
    global_fit = StructureKinematics(A_M * 1.05, F_HZ, PHASE)  # the take's average: 5 % off on either side
    w = 2 * math.pi * F_HZ
    true_e = 0.7
    for t in ((2 * math.pi * 20.3 - PHASE) / w, (2 * math.pi * 70.8 - PHASE) / w):  # before and after the step
        amp = A_M if t < 2.0 else 1.1 * A_M
        v_s_true = amp * w * math.cos(w * t + PHASE)
        v_b = v_s_true - 0.5
        v_a = v_s_true + true_e * 0.5
        v_s_model = float(global_fit.velocity(t))
        cor_model = -(v_a - v_s_model) / (v_b - v_s_model)
        imp = Impact(index=0, t_s=t, plate="bottom", cor=cor_model, cor_std=1e-4, v_ball_before_mps=v_b,
                     v_ball_after_mps=v_a, v_structure_mps=v_s_model, flight_before=0, flight_after=1,
                     t_paper_s=t)
        measured, note = with_local_structure(meas, SimpleNamespace(motion=global_fit), imp)
        assert note is not None  # 5 % of A w = 10 mm/s: a COR shift far above the floor
        assert abs(cor_model - true_e) > 10 * COR_SUPPORT_FLOOR
        # the local velocity is the truth to its noise (~4e-6 m/s -> ~1e-5 in the COR)
        assert abs(measured.cor - true_e) < 1e-4 and measured.cor_std >= imp.cor_std
        assert math.isclose(note.cor_shift, measured.cor - cor_model)
        # and where the model follows the structure, the impact is left as measured
    exact = StructureKinematics(A_M, F_HZ, PHASE)
    t0 = (2 * math.pi * 20.3 - PHASE) / w
    imp0 = replace(imp, t_s=t0, t_paper_s=t0)
    assert with_local_structure(meas, SimpleNamespace(motion=exact), imp0) == (imp0, None)
