"""Hertz damped model (Eq. 6-12) and the replay of identified parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibro_model.kinematics import StructureKinematics
from vibro_sim.cor_model import simulate_cor
from vibro_sim.deviation import deviation
from vibro_sim.forces import PerFlight
from vibro_sim.hertz_model import hertz_contact_time, hertz_single_impact, simulate_hertz, undamped_max_penetration
from vibro_sim.params import BallCavity
from vibro_sim.replay import ReplayInputs, compare_models, simulate_measured
from vibro_sim.restitution import PerPlate, Scattered

CAV = BallCavity()
S = StructureKinematics(27.0 / (2 * math.pi * 22.0) ** 2, 22.0, phase_rad=0.3)


def test_stiffness_is_eq8():
    # K = 4 sqrt(R) / (3 pi (k_b + k_s)) equals the textbook 4/3 E* sqrt(R)
    assert CAV.contact_stiffness == pytest.approx(4 / 3 * CAV.effective_modulus_pa * math.sqrt(CAV.radius_m),
                                                  rel=1e-12)


@pytest.mark.parametrize("v", [0.1, 0.5, 2.0])
def test_contact_duration_matches_hertz_formula(v):
    # Undamped sphere on a flat: t_c = 2.87 (m^2 / (R E*^2 v))^(1/5) (the constant is
    # 2.868 to 4 digits); the brief's tolerance is 2 %.
    e_eff, tc = hertz_single_impact(CAV, 1.0, v)
    assert tc == pytest.approx(hertz_contact_time(CAV, v), rel=0.02)
    assert e_eff == pytest.approx(1.0, abs=1e-6)  # no damping: no loss beyond solver error


def test_effective_cor_is_speed_invariant_with_per_impact_delta_a():
    # With delta_a = delta_max(v), c scales as v^(1/5) exactly like the Hertz time and
    # length scales, so the dimensionless impact, hence the restitution, does not
    # depend on v (only solver error, rtol 1e-10, remains).
    eff = [hertz_single_impact(CAV, 0.7, v)[0] for v in (0.1, 0.5, 2.0)]
    assert max(eff) - min(eff) < 1e-6
    assert 0.0 < eff[0] < 0.7  # Eq. 11 + no-tension clip over-damps: measured, not assumed


@pytest.mark.parametrize("e", [0.3, 0.6, 0.75, 0.95])
def test_calibrated_delta_a_restitutes_the_target(e):
    # The calibration table (52 targets, linear interpolation of a smooth monotone map)
    # leaves an interpolation error well below 1e-3 in COR.
    for v in (0.1, 1.5):
        assert hertz_single_impact(CAV, e, v, delta_a="calibrated")[0] == pytest.approx(e, abs=1e-3)


def test_eq11_calibration_table_is_what_the_hertz_impact_gives_for_any_ball():
    # The stored table (EQ11_GRID -> EQ11_EFFECTIVE) must be the effective COR of a Hertz impact with
    # delta_a = delta_max, for this rig's ball and for one 7x heavier, 2x larger, of other moduli, at other
    # speeds: the impact is self-similar, so only the solver's error (rtol 1e-10) may differ. Every 5th point.
    from vibro_sim.hertz_model import EQ11_EFFECTIVE, EQ11_GRID

    other = BallCavity(mass_kg=CAV.mass_kg * 7.3, radius_m=CAV.radius_m * 2.1, free_play_m=CAV.free_play_m,
                       gravity_mps2=9.81, ball_E_pa=CAV.ball_E_pa * 0.3, ball_nu=0.3, plate_E_pa=CAV.plate_E_pa * 2,
                       plate_nu=0.25)
    assert np.all(np.diff(EQ11_EFFECTIVE) > 0)  # monotone: invertible by interpolation
    for k in range(0, EQ11_GRID.size, 5):
        for cav, v in ((CAV, 1.0), (other, 0.3)):
            assert hertz_single_impact(cav, float(EQ11_GRID[k]), v)[0] == pytest.approx(EQ11_EFFECTIVE[k], abs=1e-8)


def test_effective_cor_rises_with_speed_for_fixed_delta_a():
    # Fixed c: the Hertz stiffness grows with penetration, so the damping ratio falls
    # with speed and the restitution rises.
    d_a = undamped_max_penetration(CAV, 0.5)
    eff = [hertz_single_impact(CAV, 0.7, v, delta_a=d_a)[0] for v in (0.1, 0.5, 2.0)]
    assert eff[0] < eff[1] < eff[2]


def _steady_state(law, t0=1.0):
    w = simulate_cor(S, CAV, law, None, y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=t0)
    return float(w.sample(t0)), float(w.velocity(t0))


def test_hertz_matches_cor_model_fed_with_its_effective_cor():
    # Same dissipation per impact => same motion up to the finite contact time: each
    # rebound is displaced by at most t_c (< 25 us for v > 0.1 m/s) times the relative
    # speed (< 2 m/s), i.e. < 50 um, without accumulation in the stable period-1 regime.
    e_top = hertz_single_impact(CAV, 0.6, 1.0)[0]
    e_bot = hertz_single_impact(CAV, 0.75, 1.0)[0]
    y0, v0 = _steady_state(PerPlate(e_top, e_bot))
    h = simulate_hertz(S, CAV, PerPlate(0.6, 0.75), None, y0_m=y0, v0_mps=v0, t0_s=1.0, t_end_s=1.5)
    c = simulate_cor(S, CAV, PerPlate(e_top, e_bot), None, y0_m=y0, v0_mps=v0, t0_s=1.0, t_end_s=1.5)
    t = np.linspace(1.0, 1.5, 3001)
    assert len(h.impacts) == len(c.impacts) > 15
    assert np.max(np.abs(h.sample(t) - c.sample(t))) < 5e-5
    # penetration stays at the Hertz scale (delta_max at 2 m/s ~ 9 um)
    assert np.max(np.abs(h.relative_position(t))) < CAV.free_play_m + undamped_max_penetration(CAV, 2.0)


def _identified():
    law = Scattered(PerPlate(0.6, 0.75), 0.04, seed=11)
    forces = PerFlight(list(np.random.default_rng(2).normal(0.0, 1e-4, 100)))
    y0, v0 = _steady_state(law)
    ref = simulate_cor(S, CAV, law, forces, y0_m=y0, v0_mps=v0, t0_s=1.0, t_end_s=2.5)
    return ref, forces


def test_replay_of_cor_model_reproduces_the_source_simulation():
    # Replaying a COR-model run from its own impacts and flight forces, started mid-way,
    # must give the same trajectory to rounding (1e-9 m).
    ref, forces = _identified()
    t_start = 1.4
    k0 = sum(1 for i in ref.impacts if i.t_s <= t_start)
    inputs = ReplayInputs(
        structure=S,
        impact_times_s=[i.t_s for i in ref.impacts], impact_plates=[i.plate for i in ref.impacts],
        impact_cors=[i.cor for i in ref.impacts],
        flight_forces_n=[forces.constant_n(k) for k in range(len(ref.impacts) + 1)],
        t_start_s=t_start, y_rel_m=float(ref.relative_position(t_start)),
        v_rel_mps=float(ref.velocity(t_start) - S.velocity(t_start)), t_end_s=2.5)
    t = np.linspace(t_start, 2.5, 1201)
    out = simulate_measured(inputs, CAV, t)
    y_cor, res = out["cor_model"]
    assert np.max(np.abs(y_cor - ref.sample(t))) < 1e-9
    assert [i.plate for i in res.impacts] == [i.plate for i in ref.impacts[k0:]]
    y_h, _ = out["hertz_model"]
    assert y_h.shape == t.shape and np.all(np.isfinite(y_h))
    assert deviation(t, y_cor, ref.sample(t)) < 1e-9
    scores = compare_models(inputs, CAV, t, ref.sample(t), models=("cor_model",))
    assert scores["cor_model"]["deviation"] < 1e-9
    # the calibrated Hertz variant restitutes the same CORs: it stays close to the source
    # (contact times ~20 us shift each rebound by < 50 um; D is a fraction of ~6 mm motion)
    cal = compare_models(inputs, CAV, t, ref.sample(t), models=("hertz_model",), hertz_delta_a="calibrated")
    assert cal["hertz_model"]["deviation"] < 0.02


def test_replay_inputs_are_validated():
    with pytest.raises(ValueError, match="3 impact times but 2 plates"):
        ReplayInputs(structure=S, impact_times_s=[0.1, 0.2, 0.3], impact_plates=["top", "bottom"],
                     impact_cors=[0.7, 0.7,
                                  0.7], flight_forces_n=[], t_start_s=0.0, y_rel_m=0.0, v_rel_mps=0.0, t_end_s=1.0)
    with pytest.raises(ValueError, match="'top' or 'bottom'"):
        ReplayInputs(structure=S, impact_times_s=[0.1], impact_plates=["side"], impact_cors=[0.7], flight_forces_n=[],
                     t_start_s=0.0, y_rel_m=0.0, v_rel_mps=0.0, t_end_s=1.0)
    with pytest.raises(ValueError, match="must exceed"):
        ReplayInputs(structure=S, impact_times_s=[], impact_plates=[], impact_cors=[], flight_forces_n=[],
                     t_start_s=1.0, y_rel_m=0.0, v_rel_mps=0.0, t_end_s=1.0)
    bad = ReplayInputs(structure=S, impact_times_s=[], impact_plates=[], impact_cors=[], flight_forces_n=[],
                       t_start_s=0.0, y_rel_m=0.01, v_rel_mps=0.0, t_end_s=0.1)
    with pytest.raises(ValueError, match="outside the free play"):
        simulate_measured(bad, CAV, [0.0, 0.05])
