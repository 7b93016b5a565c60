"""Concealed-effect cases for the discrepancy tests, without rendering frames (fast).

The synthetic rig's physics (vibro_sim.synth: build_models + simulate_window, the same code that
writes recordings) gives the true ball and structure motion; DIC is emulated by adding white Gaussian
noise of ``noise_mm`` to both tracks (0.25 um: what vibro track measures on the rig's rendered frames,
tests/test_dic_noise.py). The identification (vibro_fit.identify) then produces the results sections;
the analysis sees only those, the track and the rig. The truth mapping (contract keys) is returned
separately for scoring.
"""

from __future__ import annotations

import math

import numpy as np

from vibro_io.dictrack import DicTrack

NOISE_MM = 2.5e-4


def make_case(effects: dict, seed: int = 0, frames: int = 400, noise_mm: float = NOISE_MM,
              accel_mps2: float = 27.0, frequency_hz: float = 22.0, cor_scatter: float = 0.0,
              scale_error: float = 0.0):
    """(sections, track, rig, truth) for a synthetic recording with ``effects`` (contract names);
    ``cor_scatter``: per-impact COR scatter of the rig (SynthConfig.cor_scatter); ``scale_error``: the rig's
    image scale off by this relative amount (every tracked displacement times 1 + scale_error, as a wrong
    camera.mm_per_px gives)."""

    from vibro_fit.identify import identify
    from vibro_fit.results import results_document
    from vibro_fit.synthetic import paper_rig
    from vibro_sim.synth.scenario import SynthConfig, build_models, effects_truth
    from vibro_sim.synth.trajectory import simulate_window

    cfg = SynthConfig(effects=effects, seed=seed, frames=frames, accel_mps2=accel_mps2, frequency_hz=frequency_hz,
                      accel=False, cor_scatter=cor_scatter)
    rng = np.random.default_rng(seed)
    phase = float(rng.uniform(0.0, 2 * math.pi))
    models = build_models(cfg, phase)
    traj = simulate_window(cfg, models)
    ball = traj.ball_m * 1e3
    struct = traj.structure_m * 1e3
    seen = 1.0 + scale_error
    noise = np.random.default_rng([seed, 99])
    n = ball.size
    track = DicTrack(frame=np.arange(n), t_s=traj.frame_t_s.copy(),
                     ball_mm=seen * (ball - ball[0]) + noise.normal(0, noise_mm, n),
                     structure_mm=seen * (struct - struct[0]) + noise.normal(0, noise_mm, n),
                     ball_valid=np.full(n, 4), structure_valid=np.full(n, 24), ball_zncc=np.ones(n),
                     structure_zncc=np.ones(n), lost=np.zeros(n, bool))
    rig = paper_rig(frequency_hz=frequency_hz)
    ident = identify(track, rig)
    sections = results_document(ident, "synthetic")
    S = models.structure
    truth = {
        "schema": "vibro.truth/1",
        "effects": effects_truth(cfg),
        "structure": {"amplitude_mm": S.amplitude_m * 1e3, "frequency_hz": S.frequency_hz, "phase_rad": phase,
                      "offset_mm": S.offset_m * 1e3, "h2_ratio": S.h2_ratio, "h3_ratio": S.h3_ratio,
                      "h2_phase_rad": S.h2_phase_rad, "h3_phase_rad": S.h3_phase_rad},
        "frames": {"t_s": traj.frame_t_s.tolist(), "ball_mm": ball.tolist(), "structure_mm": struct.tolist()},
        "impacts": [{"t": i.t_s, "plate": i.plate, "cor": i.cor, "v_ball_before": i.v_ball_before_mps,
                     "v_ball_after": i.v_ball_after_mps, "v_structure": i.v_structure_mps} for i in traj.impacts],
        "free_play_mm": models.cavity.free_play_m * 1e3,
        "ball_offset_mm": float((traj.ball_m[0] - traj.structure_m[0]) * 1e3),
        "gravity_ms2": models.cavity.gravity_mps2,
        "ball_mass_kg": models.cavity.mass_kg,
    }
    return sections, track, rig, truth
