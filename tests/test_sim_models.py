"""Physics checks of the vibro_sim models with analytic answers (SI units)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from vibro_model.kinematics import StructureKinematics
from vibro_sim.cor_model import simulate_cor
from vibro_sim.deviation import deviation
from vibro_sim.forces import Coulomb, NoForce, PerFlight, Quadratic, Viscous
from vibro_sim.params import BallCavity
from vibro_sim.restitution import Constant, PerImpact, PerPlate, Scattered, VelocityDependent

F_HZ = 22.0
W = 2 * math.pi * F_HZ
CAV = BallCavity()  # paper rig: b = (16.6 - 4.77)/2 mm
B = CAV.free_play_m
G = CAV.g_eff_mps2


def shaker(accel_mps2: float = 40.0, **kw) -> StructureKinematics:
    return StructureKinematics(accel_mps2 / W ** 2, F_HZ, **kw)


def test_free_flight_is_exact_parabola():
    # Fixed structure, ball thrown from the centre: no contact before t_hit, so the
    # trajectory must be y0 + v0 t - g t^2 / 2 to rounding (1e-15 m scale).
    S = StructureKinematics(0.0, F_HZ)
    v0 = 0.2
    r = simulate_cor(S, CAV, Constant(0.7), NoForce(), y0_m=0.0, v0_mps=v0, t0_s=0.0, t_end_s=0.1)
    # first contact: bottom, where v0 t - g t^2/2 = -b
    t_hit = (v0 + math.sqrt(v0 ** 2 + 2 * G * B)) / G
    assert r.impacts and abs(r.impacts[0].t_s - t_hit) < 1e-9
    assert r.impacts[0].plate == "bottom"
    t = np.linspace(0.0, t_hit, 500)[:-1]  # at t_hit itself velocity() is the rebound's
    np.testing.assert_allclose(r.sample(t), v0 * t - 0.5 * G * t ** 2, atol=1e-14)
    np.testing.assert_allclose(r.velocity(t), v0 - G * t, atol=1e-13)


def test_every_flight_is_a_parabola_with_gravity_curvature():
    S = shaker()
    r = simulate_cor(S, CAV, PerPlate(0.6, 0.75), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.5)
    assert len(r.impacts) > 10
    for fl in r.flights[1:-1]:
        t = np.linspace(fl.t_start_s, fl.t_end_s, 20)
        y0 = r.sample(fl.t_start_s)
        v0 = r.impacts[fl.index - 1].v_ball_after_mps
        tau = t - fl.t_start_s
        np.testing.assert_allclose(r.sample(t), y0 + v0 * tau - 0.5 * G * tau ** 2, atol=1e-13)
        # Eq. 17 with no friction: the identified force is zero (rounding only)
        assert abs(fl.mean_force_n) < 1e-12


def test_impacts_lie_on_the_plates():
    S = shaker(35.0, h2_ratio=0.05, h3_ratio=0.02)
    r = simulate_cor(S, CAV, Constant(0.7), NoForce(), y0_m=0.001, v0_mps=0.0, t0_s=0.0, t_end_s=0.5)
    for imp in r.impacts:
        rel = r.relative_position(imp.t_s)
        expect = B if imp.plate == "top" else -B
        assert abs(rel - expect) < 1e-12
        # moving into the plate before, away after (relative)
        side = 1 if imp.plate == "top" else -1
        assert side * imp.v_rel_before_mps > 0 and side * imp.v_rel_after_mps <= 0
    rel = r.relative_position(np.linspace(0, 0.5, 20001))
    assert np.all(np.abs(rel) <= B + 1e-12)


def test_elastic_impacts_keep_relative_speed():
    r = simulate_cor(shaker(), CAV, Constant(1.0), NoForce(), y0_m=0.0, v0_mps=0.3, t0_s=0.0, t_end_s=0.5)
    assert len(r.impacts) > 5
    for imp in r.impacts:
        assert imp.v_rel_after_mps == pytest.approx(-imp.v_rel_before_mps, rel=1e-12)


@pytest.mark.parametrize("law", [Constant(0.7), PerPlate(0.6, 0.75), VelocityDependent(0.9, 0.2),
                                 Scattered(PerPlate(0.6, 0.75), 0.04, seed=3)])
def test_energy_across_impact_scales_with_e_squared(law):
    # In the plate's frame (infinite structure mass) the kinetic energy ratio is e^2.
    r = simulate_cor(shaker(), CAV, law, NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.4)
    assert len(r.impacts) > 5
    for imp in r.impacts:
        ratio = imp.v_rel_after_mps ** 2 / imp.v_rel_before_mps ** 2
        assert ratio == pytest.approx(imp.cor ** 2, rel=1e-12, abs=1e-15)
        assert imp.cor == pytest.approx(law.cor(imp.plate, imp.v_rel_before_mps, imp.index), abs=0)


def _reference_ode(S, cav, law, force, y0, v0, t_end, max_step=2e-5):
    """Independent reference: fine-step DOP853 with solve_ivp's event location."""
    b, m, g = cav.free_play_m, cav.mass_kg, cav.g_eff_mps2
    t, y, v, k = 0.0, y0, v0, 0
    ts, ys = [], []
    while t < t_end:
        def rhs(tt, s):
            return (s[1], -g + force.force_n(s[1], k) / m)

        def top(tt, s):
            return b - (s[0] - S.position(tt))

        def bot(tt, s):
            return s[0] - S.position(tt) + b
        top.terminal = bot.terminal = True
        top.direction = bot.direction = -1
        sol = solve_ivp(rhs, (t, t_end), (y, v), method="DOP853", rtol=1e-12, atol=1e-15,
                        max_step=max_step, events=(top, bot), dense_output=True)
        ts.append(sol.t)
        ys.append(sol.y[0])
        hit = [(te[0], p) for te, p in zip(sol.t_events, ("top", "bottom")) if len(te)]
        if not hit:
            break
        te, plate = min(hit)
        yb, vb = sol.sol(te)
        vs = S.velocity(te)
        e = law.cor(plate, vb - vs, k)
        t, y, v, k = te, S.position(te) + (b if plate == "top" else -b), vs - e * (vb - vs), k + 1
        # nudge past the contact so the event is not found again at its start
        t_n = t + 1e-9
        y, v = y + v * 1e-9, v
        t = t_n
    return np.concatenate(ts), np.concatenate(ys)


@pytest.mark.parametrize("force", [NoForce(), Coulomb(3e-4), Viscous(3e-3), Quadratic(3e-3),
                                   PerFlight([2e-4, -1e-4, 3e-4, -2e-4] * 10)])
def test_event_driven_matches_fine_step_ode(force):
    # Both integrate the same model; the DOP853 reference at rtol 1e-12 has error
    # ~1e-9 m per flight, the 1e-9 s nudge after each impact moves it by
    # <|dv| 1e-9 s ~ 1e-9 m; impacts amplify differences by ~|dv/dt| ~ 10 per flight
    # at worst over 0.25 s (11 impacts), so 1e-6 m is a fair bound (the brief's).
    S = shaker(40.0)
    law = PerPlate(0.6, 0.75)
    r = simulate_cor(S, CAV, law, force, y0_m=0.0, v0_mps=0.1, t0_s=0.0, t_end_s=0.25)
    t_ref, y_ref = _reference_ode(S, CAV, law, force, 0.0, 0.1, 0.25)
    assert len(r.impacts) >= 8
    assert np.max(np.abs(r.sample(t_ref) - y_ref)) < 1e-6


def test_coulomb_changes_sign_at_apex():
    # Fixed plates, ball launched up: rising deceleration g + F/m, falling g - F/m.
    S = StructureKinematics(0.0, F_HZ)
    F = 2e-4
    r = simulate_cor(S, CAV, Constant(0.7), Coulomb(F), y0_m=-B + 1e-4, v0_mps=0.25, t0_s=0.0, t_end_s=0.03)
    m = CAV.mass_kg
    t_apex = 0.25 / (G + F / m)
    assert r.acceleration(0.5 * t_apex) == pytest.approx(-G - F / m, rel=1e-12)
    assert r.acceleration(1.2 * t_apex) == pytest.approx(-G + F / m, rel=1e-12)
    assert abs(r.velocity(t_apex)) < 1e-12


def test_viscous_closed_form_matches_analytic():
    S = StructureKinematics(0.0, F_HZ)
    c = 5e-3
    k = c / CAV.mass_kg
    v0 = 0.3
    r = simulate_cor(S, CAV, Constant(0.7), Viscous(c), y0_m=-B + 1e-3, v0_mps=v0, t0_s=0.0, t_end_s=0.02)
    t = np.linspace(0, min(0.02, r.impacts[0].t_s if r.impacts else 0.02), 100)
    vinf = -G / k
    expect = -B + 1e-3 + vinf * t + (v0 - vinf) * (1 - np.exp(-k * t)) / k
    np.testing.assert_allclose(r.sample(t), expect, atol=1e-14)


def test_tilt_lowers_flight_acceleration():
    tilt = 40.0
    cav = BallCavity(tilt_deg=tilt)
    r = simulate_cor(StructureKinematics(0.0, F_HZ), cav, Constant(0.7), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0,
                     t_end_s=0.01)
    assert r.acceleration(0.005) == pytest.approx(-9.81 * math.cos(math.radians(tilt)), rel=1e-12)


def test_sticking_ends_and_releases_when_plate_drops_faster_than_g():
    # e = 0: the ball lands and rides the bottom plate; it must leave when Y_s'' = -g.
    S = shaker(15.0)  # 15 m/s^2 > g so the plate throws the ball
    r = simulate_cor(S, CAV, Constant(0.0), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.3)
    assert r.stuck, "expected sticking phases"
    for ph in r.stuck:
        if ph.t_end_s < 0.3:
            assert S.acceleration(ph.t_end_s) == pytest.approx(-G, abs=1e-6)
        mid = 0.5 * (ph.t_start_s + ph.t_end_s)
        assert r.relative_position(mid) == pytest.approx(-B, abs=1e-12)


def test_chattering_does_not_loop_forever():
    # Plate too weak to lift the ball (5 m/s^2 < g): bounces decay, then the ball sits.
    S = shaker(5.0)
    r = simulate_cor(S, CAV, Constant(0.5), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=1.0)
    assert not r.truncated
    assert r.stuck and r.stuck[-1].t_end_s == pytest.approx(1.0)
    assert len(r.impacts) < 200


def test_per_impact_and_per_flight_lists_are_followed():
    cors = [0.5, 0.9, 0.6, 0.8, 0.7]
    r = simulate_cor(shaker(), CAV, PerImpact(cors), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.3)
    for imp in r.impacts:
        expect = cors[imp.index] if imp.index < len(cors) else float(np.mean(cors))
        assert imp.cor == expect
    forces = [1e-4, -2e-4, 3e-4]
    r = simulate_cor(shaker(), CAV, Constant(0.7), PerFlight(forces), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.3)
    for fl in r.flights[:3]:
        assert fl.mean_force_n == pytest.approx(forces[fl.index], abs=1e-12)


def test_structure_derivatives_match_finite_differences():
    S = StructureKinematics(1e-3, F_HZ, phase_rad=0.3, offset_m=2e-3, h2_ratio=0.1, h3_ratio=0.05,
                        h2_phase_rad=0.7, h3_phase_rad=-1.1)
    t = np.linspace(0, 0.1, 50)
    h = 1e-6
    # central difference error ~ h^2 |f'''| / 6 ~ 1e-12 * (3w)^3 A ... << 1e-6 relative
    np.testing.assert_allclose((S.position(t + h) - S.position(t - h)) / (2 * h), S.velocity(t),
                               rtol=0, atol=1e-6 * S.bound(1))
    np.testing.assert_allclose((S.velocity(t + h) - S.velocity(t - h)) / (2 * h), S.acceleration(t),
                               rtol=0, atol=1e-6 * S.bound(2))
    np.testing.assert_allclose(S.position(0.0), 2e-3 + 1e-3 * (math.sin(0.3) + 0.1 * math.sin(0.6 + 0.7)
                                                             + 0.05 * math.sin(0.9 - 1.1)))


def test_deviation_of_scaled_sine():
    # y_sim = 1.01 y_exp  =>  D = 0.01 exactly (trapezoid applies to both integrals alike).
    t = np.linspace(0, 1, 1001)
    y = np.sin(2 * math.pi * 3 * t) + 0.2
    assert deviation(t, 1.01 * y, y) == pytest.approx(0.01, rel=1e-12)
    assert deviation(t, y, y) == 0.0


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match="outside the cavity"):
        simulate_cor(shaker(), CAV, Constant(0.7), None, y0_m=0.01, v0_mps=0.0, t0_s=0.0, t_end_s=0.1)
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        Constant(1.2)
    with pytest.raises(ValueError, match="force_n"):
        Coulomb(-1.0)
    with pytest.raises(ValueError, match="lengths differ"):
        deviation([0, 1], [0, 1, 2], [0, 1])
    with pytest.raises(ValueError, match="zero everywhere"):
        deviation([0, 1], [0, 1], [0, 0])
    with pytest.raises(ValueError, match="frequency_hz"):
        StructureKinematics(1e-3, 0.0)
    r = simulate_cor(shaker(), CAV, Constant(0.7), None, y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.1)
    with pytest.raises(ValueError, match="outside the simulated span"):
        r.sample(0.2)


@pytest.mark.parametrize("overshoot", [1e-9, -1e-9])
def test_grazing_contact_between_scan_points_is_not_missed(overshoot):
    # Fixed plates; the ball's apex is 1 nm above (or below) the top contact height.
    # Above, the gap is negative only for 2 sqrt(2e-9/g) = 29 us, shorter than the
    # 100 us scan grid: the contact must still be found, at t_apex - sqrt(2e-9/g).
    S = StructureKinematics(0.0, F_HZ)
    h = B + overshoot
    v0 = math.sqrt(2 * G * h)
    r = simulate_cor(S, CAV, Constant(0.7), NoForce(), y0_m=0.0, v0_mps=v0, t0_s=0.0, t_end_s=v0 / G + 1e-3)
    if overshoot > 0:
        assert r.impacts and r.impacts[0].plate == "top"
        assert r.impacts[0].t_s == pytest.approx(v0 / G - math.sqrt(2 * overshoot / G), abs=1e-9)
    else:
        assert not r.impacts
