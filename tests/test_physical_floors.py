"""Physical floors (issue 38, item 4): a value is refused, or a catalogue term claimed, only when it is
significant beyond its sigma AND beyond its physical floor (docs/method.md, "Physical floors").

The floors are 1e-3 of the ball's weight for a force in flight and 1e-3 for a COR change. Every case below
sits a factor of 3 or more from its floor, so that a rule on the wrong side of the floor cannot pass by the
noise of the estimate; the statistical premise (significant beyond the test's threshold) is asserted too,
so a case below the floor is one that the statistical test alone would have refused or claimed.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from discrepancy_cases import make_case

from vibro_app.cli import main
from vibro_discrepancy import run_discrepancy
from vibro_discrepancy.library import COR_EFFECT_FLOOR, FORCE_FLOOR_OF_WEIGHT
from vibro_discrepancy.select import ALPHA, MIN_EXPLAINED_SIGMA, MIN_HARMONIC_SIGMA
from vibro_fit.cross_checks import consistency_checks
from vibro_fit.identify import identify
from vibro_fit.plausibility import (
    COR_FLOOR,
    FRICTION_FLOOR_OF_WEIGHT,
    cor_outside_bounds,
    friction_balance,
    negative_friction,
    physical_plausibility,
    z_threshold,
)
from vibro_fit.synthetic import paper_rig, sample_track, simulate
from vibro_model.constants import G_MPS2
from vibro_model.results import Flight, Impact

M_KG = 1.82e-4                      # the paper's ball (paper_rig, the synthetic rig)
WEIGHT_N = M_KG * G_MPS2
FLOOR_N = FRICTION_FLOOR_OF_WEIGHT * WEIGHT_N


# ---------------------------------------------------------------- the cross-check's rule on constructed flights
def _flights(gain_n: float, sd_n: float, n: int, seed: int) -> list[Flight]:
    """``n`` free flights alternating up/down with a force ``gain_n`` along the motion (energy fed in: up on
    the up-flights, down on the down-flights; Eq. 17 sign, + up), each measured with noise ``sd_n``."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        up = k % 2 == 1
        f = (gain_n if up else -gain_n) + rng.normal(0.0, sd_n)
        out.append(Flight(index=k, t_first_frame_s=0.0, t_last_frame_s=0.02, a_mps2=-4.9, b_mps=0.0, c_m=0.0,
                          direction="up" if up else "down", friction_n=f, friction_std_n=sd_n,
                          rms_residual_m=2.5e-7, n_points=20, free=True))
    return out


def _rig():
    return SimpleNamespace(ball=SimpleNamespace(mass_kg=M_KG))


def test_friction_above_its_floor_and_significant_is_refused():
    # 5x the floor fed in, measured at 1/10 of the floor per flight: refused, its size measured
    sd = 0.1 * FLOOR_N
    flights = _flights(5 * FLOOR_N, sd, 40, seed=1)
    out = negative_friction(flights, M_KG)
    assert out is not None
    assert out["dissipative_n"] == pytest.approx(-5 * FLOOR_N, abs=5 * out["std_n"])
    assert out["floor_n"] == pytest.approx(FLOOR_N)
    findings = physical_plausibility([], flights, None, _rig(), structure_moves=False)
    assert [f.check for f in findings] == ["negative_friction"] and findings[0].refuses
    assert friction_balance(flights, M_KG)["verdict"] == "feeds_energy"


def test_friction_below_its_floor_is_zero_within_it_however_significant():
    # 0.2 of the floor fed in, measured at 1/100 of the floor per flight over 400 flights: many sigma from
    # zero (the statistical test alone refuses it), yet physically negligible: not refused, zero within the floor
    sd = 0.01 * FLOOR_N
    flights = _flights(0.2 * FLOOR_N, sd, 400, seed=2)
    bal = friction_balance(flights, M_KG)
    assert bal["significant"] and bal["z"] > 3 * z_threshold(1)
    assert bal["verdict"] == "zero_within_floor" and abs(bal["dissipative_n"]) < bal["floor_n"]
    assert "zero within the floor" in bal["words"]
    assert negative_friction(flights, M_KG) is None
    assert physical_plausibility([], flights, None, _rig(), structure_moves=False) == []


def test_real_friction_is_reported_dissipative_not_refused():
    flights = _flights(-5 * FLOOR_N, 0.1 * FLOOR_N, 40, seed=3)   # opposes the motion
    assert negative_friction(flights, M_KG) is None
    assert friction_balance(flights, M_KG)["verdict"] == "dissipative"


def _impact(k: int, cor: float, sd: float) -> Impact:
    return Impact(index=k, t_s=0.01 * k, plate="top" if k % 2 else "bottom", cor=cor, cor_std=sd,
                  v_ball_before_mps=0.5, v_ball_after_mps=-0.35, v_structure_mps=0.0)


def test_cor_outside_0_1_needs_to_be_beyond_the_floor_too():
    # a hard contact's CORs at 1 + 0.3 floor, 2000 impacts at sd 1e-3: the mean is ~13 sigma above 1 but within
    # the floor -> no alarm; at 1 + 3 floors (and far beyond sigma) -> refused on both plates and overall
    rng = np.random.default_rng(4)
    sd = 1e-3
    near = [_impact(k, 1.0 + 0.3 * COR_FLOOR + rng.normal(0, sd), sd) for k in range(2000)]
    mean = float(np.mean([i.cor for i in near]))
    assert (mean - 1.0) / (sd / math.sqrt(len(near))) > z_threshold(1)
    assert cor_outside_bounds(near) is None
    above = [_impact(k, 1.0 + 3 * COR_FLOOR + rng.normal(0, sd), sd) for k in range(2000)]
    out = cor_outside_bounds(above)
    assert out is not None and out["all"] is not None and set(out["plates"]) == {"top", "bottom"}
    assert out["all"][0] == pytest.approx(1.0 + 3 * COR_FLOOR, abs=5 * out["all"][1])


# ---------------------------------------------------------------- the cross-checks on an identified DIC track
def _identified(gain_n: float, noise_mm: float, seconds: float):
    """A DIC track of the analytic rig (exact parabolas) with a force ``gain_n`` along the motion on every
    flight (energy fed in), identified and cross-checked."""
    truth = simulate(duration_s=seconds + 0.1, force_up_n=gain_n, force_down_n=-gain_n)
    track = sample_track(truth, n_frames=int(seconds * 1000), noise_mm=noise_mm, seed=5)
    rig = paper_rig()
    ident = identify(track, rig)
    return consistency_checks(ident, track, rig)


def test_track_with_energy_fed_in_above_the_floor_is_refused():
    findings, evidence = _identified(5 * FLOOR_N, 2.5e-4, 1.5)
    refusal = [f for f in findings if f.check == "negative_friction"]
    assert refusal and refusal[0].refuses
    ev = refusal[0].evidence
    assert ev["dissipative_n"] == pytest.approx(-5 * FLOOR_N, abs=5 * ev["std_n"] + 0.2 * FLOOR_N)
    assert evidence["friction"]["verdict"] == "feeds_energy"


def test_track_with_energy_fed_in_below_the_floor_is_not_refused():
    # 0.3 of the floor fed in; 3 s of a clean track make it significant (the premise), the floor keeps it
    findings, evidence = _identified(0.3 * FLOOR_N, 5e-5, 3.0)
    fr = evidence["friction"]
    assert fr["significant"] and fr["dissipative_n"] < 0
    assert fr["verdict"] == "zero_within_floor"
    assert not any(f.check == "negative_friction" for f in findings)
    assert not any(f.refuses for f in findings)


# ---------------------------------------------------------------- the discrepancy catalogue's floors
def _stage_decision(doc: dict, stage: str, label: str) -> dict:
    return next(c for c in doc["stages"][stage]["candidates"] if c["candidate"] == label)


@pytest.mark.parametrize("effects,noise_mm,stage,label", [
    # Coulomb friction at 0.3 of the force floor
    ({"coulomb_friction": {"force_n": 0.3 * FORCE_FLOOR_OF_WEIGHT * WEIGHT_N}}, 7e-5, "flights", "coulomb_friction"),
    # a tilt of 1.5 deg: g (1 - cos) = 3.4e-4 g, 0.34 of the floor
    ({"gravity_tilt": {"tilt_deg": 1.5}}, 7e-5, "flights", "gravity_tilt"),
    # a 2nd harmonic of 1e-4: COR change (1 + e) 2 h2 A w / |v_rel| ~ 1e-4, 0.1 of the COR floor
    ({"structure_harmonics": {"h2_ratio": 1e-4, "h3_ratio": 0.0}}, 2.5e-5, "structure", "harmonic 2"),
])
def test_term_below_its_floor_is_not_a_finding(effects, noise_mm, stage, label):
    # DIC noise well below the synthetic rig's 0.25 um, so that the term is significant and visible above the
    # noise (the statistical rules accept it) but physically negligible: no finding, not even 'unexplained'
    sections, track, rig, _ = make_case(effects, seed=5, noise_mm=noise_mm)
    doc = run_discrepancy(sections, track, rig).document
    dec = _stage_decision(doc, stage, label)
    assert dec["p_value"] < ALPHA
    assert dec["explained"] >= (MIN_EXPLAINED_SIGMA if stage == "flights" else MIN_HARMONIC_SIGMA)
    assert not dec["accepted"] and "negligible" in dec["note"]
    assert doc["findings"] == []
    assert not doc["stages"][stage]["unexplained"]


def test_term_above_its_floor_is_still_found():
    # the same clean track with Coulomb friction at 3x the floor: found, with its size
    force = 3 * FORCE_FLOOR_OF_WEIGHT * WEIGHT_N
    sections, track, rig, _ = make_case({"coulomb_friction": {"force_n": force}}, seed=5, noise_mm=7e-5)
    doc = run_discrepancy(sections, track, rig).document
    assert [f["effect"] for f in doc["findings"]] == ["coulomb_friction"]
    f = doc["findings"][0]
    assert f["parameters"]["force_n"] == pytest.approx(force, abs=5 * f["parameters_std"]["force_n"])


def test_harmonic_floor_is_a_cor_change():
    # the rule's unit: the harmonic's plate velocity at impact as a COR change (Eq. 16 differentiated)
    from vibro_discrepancy.library import StructureHarmonics

    h = StructureHarmonics()
    # h2 = 1e-3 on a drive of 0.2 m/s against impacts at 0.4 m/s, e = 0.7: 1.7 * 2 * 1e-3 * 0.5 = 1.7e-3
    assert h.cor_effect(2, 1e-3, 0.2, 0.7, 0.4) == pytest.approx(1.7e-3)
    assert h.cor_effect(2, 1e-3, 0.2, 0.7, 0.4) > COR_EFFECT_FLOOR and not h.negligible(2, 1e-3, 0.2, 0.7, 0.4)
    assert h.negligible(2, 1e-4, 0.2, 0.7, 0.4)


# ---------------------------------------------------------------- end to end: the 20,000-frame take of issue 38
def test_long_take_without_friction_is_neither_refused_nor_claimed(tmp_path):
    # vibro synth --frames 20000 (no effect), vibro analyze --no-report: the whole pipeline over the take length
    # issue 38 was about refuses nothing and claims nothing. On this rig the premise of the cases above (a bias
    # significant by its sigma alone) does not arise: measured at fb0cb7a, the flights' dissipative friction came
    # out 4.9e-9 +- 2.0e-8 N (z -0.25; 0.003 of the floor) and no discrepancy candidate reached p < 0.01, so this
    # case guards the long take end to end; the floors themselves are tested on the constructed tracks above
    from vibro_sim.synth import SynthConfig, synthesize

    synthesize(tmp_path / "rec", SynthConfig(frames=20000), progress=False)
    rc = main(["analyze", str(tmp_path / "rec"), "--out", str(tmp_path / "out"), "--no-report", "--no-progress"])
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert rc == 0, doc["consistency"]
    assert not doc["consistency"]["refused"]
    assert not any(f["check"] == "negative_friction" for f in doc["consistency"]["findings"])
    fr = doc["consistency"]["checks"]["friction"]
    assert fr["verdict"] == "zero_within_floor" and abs(fr["dissipative_n"]) <= fr["floor_n"]
    assert fr["floor_n"] == pytest.approx(FLOOR_N)
    assert doc["discrepancy"]["findings"] == []
    assert doc["cor_summary"]


def test_a_tilt_the_scales_uncertainty_could_make_is_said_to_be_one_and_not_claimed() -> None:
    """A scale off by x scales every flight's acceleration by 1 + x, as a tilt scales gravity by cos(tilt): with
    rig.yaml's scale sigma (camera.mm_per_px_rel_std, vibro init writes it) a gravity change within 3 of them is
    said to be either. A 0.3 % low scale looks like a 4.4 deg tilt; init's scale sigma is ~0.1 %."""
    from types import SimpleNamespace

    from vibro_discrepancy.engine import scale_could_explain
    from vibro_discrepancy.library import FLIGHT_TERMS

    tilt = next(t for t in FLIGHT_TERMS if t.effect == "gravity_tilt")
    coulomb = next(t for t in FLIGHT_TERMS if t.effect == "coulomb_friction")
    g = 9.80665
    coef = g * (1 - math.cos(math.radians(4.4)))  # 0.29 % of g
    meas = SimpleNamespace(g_mps2=g, scale_rel_std=0.0013)
    note = scale_could_explain(tilt, coef, meas)
    assert note["scale_could_explain"] and "off by -0.29 %" in note["scale_note"]
    assert scale_could_explain(tilt, g * (1 - math.cos(math.radians(30.0))), meas) == {}  # 13 %: a tilt
    assert scale_could_explain(tilt, coef, SimpleNamespace(g_mps2=g, scale_rel_std=0.0)) == {}  # sigma unknown
    assert scale_could_explain(coulomb, coef, meas) == {}  # only gravity looks like a scale
