"""Issue 39: a plate that creeps over the take (vibro_fit.plate_motion, the synthetic rig's ``plate_creep``).

Ground truth: (1) the event simulator's own impacts on a creeping top plate (physics: the ball meets the plate
where it is, with its velocity); (2) contact levels and impacts built here with a known plate motion and white
noise of the rendered recordings' level noise (0.1 um); (3) a rendered recording (``vibro synth --effect
plate_creep`` with a quadratic drag, so the COR passes through the discrepancy analysis' re-measurement too) and
its truth file. Properties: a creep is measured within its sigma and taken into the CORs, a step, noise, or a
creep too small to move a COR are left alone; on the rendered recording the published CORs hold the truth within
2 sigma on both plates where, without the plate's velocity, the top plate's do not.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import vibro_fit.plate_motion as pm
from vibro_fit.impacts import ImpactFit
from vibro_io.plate_motion import plate_creeps
from vibro_model.errors import RecordingError
from vibro_model.kinematics import StructureKinematics
from vibro_sim.cor_model import simulate_cor
from vibro_sim.params import BallCavity
from vibro_sim.plates import MovedPlate
from vibro_sim.restitution import Constant

LEVEL_NOISE_UM = 0.1    # contact-level noise of the rendered recordings (0.085-0.11 um measured there)
V_REL_MPS = 0.6         # relative impact speed of the synthetic rig's regime
COR = 0.7
NOISE_COR = 4e-5        # a rendered recording's COR sigma


# ---------------------------------------------------------------- the synthetic rig's creeping plate
def test_the_simulated_ball_meets_a_creeping_plate_where_it_is_and_at_its_speed() -> None:
    S = StructureKinematics(amplitude_m=1.0e-3, frequency_hz=22.0, phase_rad=0.3, offset_m=0.0)
    cavity = BallCavity(mass_kg=2.0e-3, radius_m=4e-3, free_play_m=1.0e-3)
    rate = 2e-4     # 200 um/s: far above the solver's 1e-12 s contact times, so a plate held still would show
    top = MovedPlate(S, (rate, 0.0))
    res = simulate_cor(S, cavity, Constant(COR), y0_m=0.0, t0_s=0.0, t_end_s=1.5, plates={"top": top})
    tops = [i for i in res.impacts if i.plate == "top"]
    assert len(tops) > 20
    for imp in tops:
        t = imp.t_s
        # the ball's centre is on the moved plate: y = S(t) + b + rate t (to the solver's contact tolerance)
        assert abs(float(res.sample(t)) - (float(S.position(t)) + cavity.free_play_m + rate * t)) < 1e-9
        assert imp.v_structure_mps == pytest.approx(float(S.velocity(t)) + rate, abs=1e-12)
        e = -(imp.v_ball_after_mps - imp.v_structure_mps) / (imp.v_ball_before_mps - imp.v_structure_mps)
        assert e == pytest.approx(COR, abs=1e-12)
    for imp in (i for i in res.impacts if i.plate == "bottom"):
        assert abs(float(res.sample(imp.t_s)) - (float(S.position(imp.t_s)) - cavity.free_play_m)) < 1e-9


def test_a_creep_that_would_close_the_cavity_is_refused_naming_its_parameter() -> None:
    from vibro_sim.synth import SynthConfig, SynthError

    with pytest.raises(SynthError, match="creep_um_per_s"):
        # 500 um/s over the lead-in and 20 s of frames: past half the default free play
        SynthConfig(effects={"plate_creep": {"creep_um_per_s": -500.0}}, frames=20000)


# ---------------------------------------------------------------- levels with a known plate motion
def _impacts(level_um, rng: np.random.Generator, n: int = 33, span_s: float = 1.45) -> list[ImpactFit]:
    """Top-plate impacts whose plate is at ``level_um(t)`` against the structure and moves at its derivative:
    measured as Eq. 16 measures them (the structure's velocity), with COR noise and level noise."""
    t = np.linspace(0.04, 0.04 + span_s, n)
    out = []
    for k, tk in enumerate(t):
        vs = 0.1 * math.sin(7.0 * tk)
        dt = 1e-4
        v_plate = 1e-6 * (level_um(tk + dt) - level_um(tk - dt)) / (2 * dt)
        e = COR + rng.normal(0.0, NOISE_COR)
        vb = vs + v_plate + V_REL_MPS
        va = vs + v_plate - e * V_REL_MPS
        measured = -(va - vs) / (vb - vs)
        out.append(ImpactFit(index=k, t_s=float(tk), plate="top", cor=float(measured), cor_std=NOISE_COR,
                             v_ball_before_mps=vb, v_ball_after_mps=va, v_structure_mps=vs, method="paper",
                             y_rel_mm=1e-3 * (level_um(tk) + rng.normal(0.0, LEVEL_NOISE_UM)),
                             flight_before=k, flight_after=k + 1, cor_paper=float(measured)))
    return out


def _true_cor(imp: ImpactFit, level_um) -> float:
    dt = 1e-4
    v_plate = 1e-6 * (level_um(imp.t_s + dt) - level_um(imp.t_s - dt)) / (2 * dt)
    vs = (0.1 * math.sin(7.0 * imp.t_s)) + v_plate
    return -(imp.v_ball_after_mps - vs) / (imp.v_ball_before_mps - vs)


def test_a_creep_is_measured_within_its_sigma_and_taken_into_the_cors() -> None:
    rng = np.random.default_rng(5)
    rate = 40.0

    def level(t):
        return 500.0 + rate * t

    imps = _impacts(level, rng)
    moved, motions = pm.plate_motion_pass(imps)
    top = motions["top"]
    assert top.shape == "creep" and top.applied
    assert abs(top.rate_um_per_s - rate) < 4 * top.rate_std_um_per_s
    # the rate's sigma is what white level noise gives a line over this span (within 30 %: 33 points)
    t = np.array([i.t_s for i in imps])
    expected_sd = LEVEL_NOISE_UM / math.sqrt(np.sum((t - t.mean()) ** 2))
    assert top.rate_std_um_per_s == pytest.approx(expected_sd, rel=0.3)
    before = np.array([i.cor - _true_cor(i, level) for i in imps])
    after = np.array([i.cor - _true_cor(i, level) for i in moved])
    shift = (1 + COR) * 1e-6 * rate / V_REL_MPS              # what Eq. 16 misses with the structure's velocity
    assert abs(np.mean(before) + shift) < 0.1 * shift
    # what is left is the fitted velocity's own error: within 4 of the sigma it added to each COR
    added = np.array([math.sqrt(m.cor_std ** 2 - i.cor_std ** 2) for m, i in zip(moved, imps)])
    assert np.all(added > 0) and np.all(np.abs(after) < 4 * added)
    assert np.max(added) < 0.1 * NOISE_COR                     # and it is small beside the noise
    assert all(m.cor_paper == m.cor for m in moved)
    assert motions["bottom"].shape == "too_few" and not motions["bottom"].applied


def test_a_step_noise_or_a_negligible_creep_leave_the_cors_alone() -> None:
    rng = np.random.default_rng(6)
    cases = {
        "step": lambda t: 500.0 + (60.0 if t > 0.7 else 0.0),
        "still": lambda t: 500.0 + 0.0 * t,
        # 0.5 um/s: ~40 sigmas of the rate, and it moves a COR by 1.4e-6, 0.04 of its noise
        "negligible": lambda t: 500.0 + 0.5 * t,
    }
    for name, level in cases.items():
        imps = _impacts(level, rng)
        moved, motions = pm.plate_motion_pass(imps)
        top = motions["top"]
        assert not top.applied, (name, top.reason)
        assert [m.cor for m in moved] == [i.cor for i in imps], name
        if name == "step":
            assert top.shape == "step" and abs(top.step_um - 60.0) < 1.0 and abs(top.step_time_s - 0.7) < 0.05
        if name == "negligible":
            assert top.shape == "creep" and abs(top.rate_um_per_s) > 5 * top.rate_std_um_per_s
            assert "COR" in top.reason


def test_a_wild_contact_level_is_left_out_not_taken_for_a_motion() -> None:
    rng = np.random.default_rng(8)
    imps = _impacts(lambda t: 500.0 + 0.0 * t, rng)
    imps[20] = replace(imps[20], y_rel_mm=imps[20].y_rel_mm + 0.02)     # one level 20 um (200 sigma) off
    _, motions = pm.plate_motion_pass(imps)
    top = motions["top"]
    assert top.shape == "still" and not top.applied and top.levels_left_out == 1
    assert top.level_rms_um < 2 * LEVEL_NOISE_UM


def test_the_section_round_trips_through_the_message_and_a_damaged_one_is_refused() -> None:
    rng = np.random.default_rng(7)
    _, motions = pm.plate_motion_pass(_impacts(lambda t: 10.0 - 25.0 * t, rng))
    section = {p: m.to_dict() for p, m in motions.items()}
    creeps = plate_creeps(json.loads(json.dumps(section)))
    assert set(creeps) == {"top"}
    for t in (0.1, 0.9):
        assert creeps["top"].velocity_mps(t) == pytest.approx(motions["top"].velocity_mps(t)[0], rel=1e-12)
    from vibro_model.results import StructureMotion
    from vibro_ros import convert

    msg = convert.structure_to_message(StructureMotion(amplitude_m=1e-3, frequency_hz=22.0, phase_rad=0.0,
                                                       offset_m=0.0), 1.0, 0, plate_motion=section)
    assert convert.structure_sections(msg)["plate_motion"] == json.loads(json.dumps(section))
    for key, bad in (("applied", "yes"), ("coef_um", ["x"]), ("t_ref_s", None)):
        damaged = json.loads(json.dumps(section))
        damaged["top"][key] = bad
        with pytest.raises(RecordingError, match=f"plate_motion.top.{key}"):
            plate_creeps(damaged)


# ---------------------------------------------------------------- a rendered recording
CREEP_UM_PER_S = 40.0


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> dict:
    """``vibro synth`` with a creeping upper plate and a quadratic drag (1500 frames), analysed."""
    base = tmp_path_factory.mktemp("creep")
    rec, out = base / "creep", base / "out"
    cli = [sys.executable, "-m", "vibro_app.cli"]
    made = subprocess.run([*cli, "synth", "--out", str(rec), "--seed", "1", "--frames", "1500", "--no-accel",
                           "--no-progress", "--effect", "plate_creep", "--param", f"creep_um_per_s={CREEP_UM_PER_S}",
                           "--effect", "quadratic_drag", "--param", "coefficient_ns2_per_m2=5e-4"],
                          capture_output=True, text=True, timeout=600)
    assert made.returncode == 0, made.stderr
    ran = subprocess.run([*cli, "analyze", str(rec), "--out", str(out), "--no-report", "--no-progress"],
                         capture_output=True, text=True, timeout=600)
    assert ran.returncode == 0, ran.stderr
    return {"results": json.loads((out / "results.json").read_text()),
            "truth": json.loads(Path(str(rec) + ".truth.json").read_text())}


def _errors(results: dict, truth: dict, plate: str, without_creep: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(COR errors, sigmas) of the published impacts on ``plate``; ``without_creep``: Eq. 16 again with the
    structure's velocity (the published v_structure less the creep the section states)."""
    creeps = plate_creeps(results.get("plate_motion"))
    tt = np.array([i["t"] for i in truth["impacts"]])
    errs, sds = [], []
    for imp in results["impacts"]:
        if imp["plate"] != plate or imp.get("cor") is None:
            continue
        cor = imp["cor"]
        if without_creep and plate in creeps:
            vs = imp["v_structure"] - creeps[plate].velocity_mps(imp["t"])
            cor = -(imp["v_ball_after"] - vs) / (imp["v_ball_before"] - vs)
        k = int(np.argmin(np.abs(tt - imp["t"])))
        errs.append(cor - truth["impacts"][k]["cor"])
        sds.append(imp["cor_std"])
    return np.array(errs), np.array(sds)


def test_on_a_rendered_recording_the_creep_is_measured_and_the_cors_hold_the_truth(rendered) -> None:
    r, truth = rendered["results"], rendered["truth"]
    top = r["plate_motion"]["top"]
    assert top["shape"] == "creep" and top["applied"], top["reason"]
    assert abs(top["rate_um_per_s"] - CREEP_UM_PER_S) < 5 * top["rate_std_um_per_s"]
    assert not r["plate_motion"]["bottom"]["applied"]
    assert "quadratic_drag" in {f["effect"] for f in r["discrepancy"]["findings"]}
    for plate in ("top", "bottom"):
        e, s = _errors(r, truth, plate)
        assert e.size > 25
        assert np.mean(np.abs(e) < 2 * s) >= 0.9, plate
    e, s = _errors(r, truth, "top", without_creep=True)
    assert np.mean(np.abs(e) < 2 * s) < 0.9      # without the plate's velocity the sigmas do not hold
    # the discrepancy analysis still locates the plate's drift as physics outside the library
    drift = [m for f in r["discrepancy"]["findings"] if f["effect"] == "unexplained" for m in f.get("mismatches", [])
             if m.get("series") == "contact_level" and m.get("plate") == "top"]
    assert drift, r["discrepancy"]["findings"]
    travel = CREEP_UM_PER_S * (drift[0]["t_to_s"] - drift[0]["t_from_s"])
    assert drift[0]["size"] == pytest.approx(travel, rel=0.1)
    # and models it: the simulation replays the plate's measured creep and the deviation falls to the noise's
    # order (a model that fits leaves D_r ~ the ball noise / its rms travel: ~1e-4 on this rig)
    (un,) = [f for f in r["discrepancy"]["findings"] if f["effect"] == "unexplained"]
    assert un["parameters"] == {} and un["plate_motion"]["plates"] == ["top"]
    assert abs(un["plate_motion"]["mean_rate_um_per_s"]["top"] - CREEP_UM_PER_S) < 5 * top["rate_std_um_per_s"]
    assert un["deviation_after"] < 0.1 * un["deviation_before"] and un["deviation_after"] < 1e-4
    from vibro_app.findings_text import finding_sentence, findings_lines

    assert finding_sentence(un).startswith("A plate moves against the tracked structure") and "top plate" in \
        finding_sentence(un)
    assert any("a plate moves against the structure: top" in line for line in findings_lines(r["discrepancy"]))
    # the report's per-impact table flags the impacts whose plate's creep is in Eq. 16, and only those
    from vibro_app.report_tables import creeping_plates, impact_rows

    rows = impact_rows(r["impacts"], creeping_plates(r))
    assert {row["plate"] for row in rows if "plate creeps (in Eq. 16)" in row["flags"]} == {"top"}
    assert all("plate creeps (in Eq. 16)" in row["flags"] for row in rows if row["plate"] == "top" and row["cor"])


# ---------------------------------------------------------------- both plates alike: not a plate
def test_levels_that_move_alike_on_both_plates_are_one_common_mode_pattern() -> None:
    from vibro_discrepancy.systematic import Mismatch, common_mode_levels

    def level(plate, shape, size, at=0.4, span=(0.0, 1.5)):
        return Mismatch(series="contact_level", shape=shape, size=size, unit="um", t_from_s=span[0],
                        t_to_s=span[1], p_value=1e-8, statistic=40.0, plate=plate,
                        step_time_s=at if shape == "step" else None)

    alike = common_mode_levels([level("top", "step", 1.16, 0.380), level("bottom", "step", 1.26, 0.356)], 22.0)
    assert all(m.common_mode for m in alike) and "no plate moved" in alike[0].words()
    for pair in ([level("top", "step", 60.0, 0.15)],                                   # one plate: a plate
                 [level("top", "step", 1.2, 0.38), level("bottom", "step", -1.2, 0.36)],  # opposite: the gap
                 [level("top", "step", 3.0, 0.38), level("bottom", "step", 1.0, 0.36)],   # sizes differ
                 [level("top", "step", 1.2, 0.20), level("bottom", "step", 1.2, 0.90)],   # at other times
                 [level("top", "trend", 56.0), level("bottom", "step", 50.0)]):          # other shapes
        assert not any(m.common_mode for m in common_mode_levels(pair, 22.0)), pair


def test_a_spinning_ball_moves_both_levels_alike_and_no_plate_is_claimed(tmp_path) -> None:
    """A rendered recording whose ball spins N(0, 0.3 rad/s) per flight (no other physics): both contact levels
    move alike (the rotation leaking into the mesh's translation: over 1500 frames of this seed a 1.2 um step of
    both, which the analysis reported as an unexplained plate-height step; over these 600 a 1.6-1.9 um drift of
    both, located with p < 1e-3). The test holds that premise (both plates' patterns are located) and asserts a
    common-mode note, no finding, no plate motion applied."""
    rec, out = tmp_path / "spin", tmp_path / "out"
    cli = [sys.executable, "-m", "vibro_app.cli"]
    made = subprocess.run([*cli, "synth", "--out", str(rec), "--seed", "1", "--frames", "600", "--no-accel",
                           "--no-progress", "--spin-sigma-rad-s", "0.3"], capture_output=True, text=True, timeout=600)
    assert made.returncode == 0, made.stderr
    ran = subprocess.run([*cli, "analyze", str(rec), "--out", str(out), "--no-report", "--no-progress"],
                         capture_output=True, text=True, timeout=600)
    assert ran.returncode == 0, ran.stderr
    r = json.loads((out / "results.json").read_text())
    assert r["discrepancy"]["findings"] == []
    notes = [n for n in r["discrepancy"]["notes"] if "the other plate's height does the same" in n]
    assert {n.split(" plate height")[0] for n in notes} == {"top", "bottom"}
    assert not any(m["applied"] for m in r["plate_motion"].values())


def test_the_joint_method_is_told_its_fixed_plate_level_does_not_hold() -> None:
    imps = _impacts(lambda t: 500.0 + 40.0 * t, np.random.default_rng(9))
    _, motions = pm.plate_motion_pass(imps)
    paper, joint = pm.plate_motion_notes(motions, "paper"), pm.plate_motion_notes(motions, "joint")
    assert not any("joint method" in n for n in paper) and any("creeps" in n for n in paper)
    (warn,) = [n for n in joint if "joint method" in n]
    assert warn.startswith("top plate") and f"{motions['top'].travel_um:+.2f} um" in warn
