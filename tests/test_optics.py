"""Issue 40: without a camera calibration, a lens's signature is named as a probable optical effect with the
remedy, not claimed as physics (vibro_discrepancy.optics).

Ground truth: ``vibro synth --lens-k1`` renders the rig through a barrel lens (its scale ~1.5 % lower at the
plates than at the image centre) and, with ``--no-calibration-file``, leaves the calibration out of rig.yaml, as a
lab that forgot to calibrate; the synthetic rig has no physics beyond the baseline. Forces that do depend on the
ball's position or speed (tests/discrepancy_cases.py, exact physics) must not be taken for a lens.
"""

from __future__ import annotations

import pytest
from discrepancy_cases import make_case
from shared_runs import lens_recordings

from vibro_discrepancy.data import measured_from_sections
from vibro_discrepancy.optics import NOISE_RATIO, lens_check, lens_findings
from vibro_model.results import DiscrepancyFinding


@pytest.fixture(scope="module")
def through_a_lens(tmp_path_factory) -> dict:
    """One recording through the lens, analysed with its calibration and, from a copy whose rig.yaml lost the
    ``camera.calibration`` line (the lab that forgot), without it: the same frames both ways (made once per test
    run, shared with tests/test_camera_calibration.py)."""
    return lens_recordings(tmp_path_factory)


def test_a_lens_without_calibration_is_named_with_its_remedy_not_claimed(through_a_lens):
    d = through_a_lens["forgotten"]["doc"]["discrepancy"]
    assert d["lens_check"]["signature"]
    assert d["lens_check"]["residual_before_x_noise"] > NOISE_RATIO >= d["lens_check"]["residual_after_x_noise"]
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]     # no catalogue physics claimed
    f = d["findings"][0]
    assert f["probable_cause"] == "lens_distortion" and "camera.calibration" in f["where"]
    assert "vibro calibrate" in through_a_lens["forgotten"]["stdout"]  # the user sees the remedy


def test_the_calibrated_camera_shows_no_lens_and_no_finding(through_a_lens):
    d = through_a_lens["calibrated"]["doc"]["discrepancy"]
    assert "lens_check" not in d                                       # positions undistorted: nothing to test
    assert d["findings"] == []


@pytest.mark.parametrize("effects", [
    {"position_force": {"weight_fraction": 0.25, "decay_mm": 3.0}},   # a force that depends on position
    {"quadratic_drag": {"coefficient_ns2_per_m2": 5e-4}},             # ... on speed
    {"coulomb_friction": {"force_n": 2e-4}},                          # ... on the direction
    {"gravity_tilt": {"tilt_deg": 10.0}},                             # a constant one
    {},                                                               # none
])
def test_physics_is_not_taken_for_a_lens(effects):
    sections, track, rig, _ = make_case(effects, seed=1, frames=1500)
    check = lens_check(measured_from_sections(sections, track, rig))
    assert check is not None and not check.signature


def test_the_lens_verdict_keeps_what_the_findings_said():
    from vibro_discrepancy.optics import LensCheck

    harm = DiscrepancyFinding("structure_harmonics", {"h2_ratio": 1e-3, "h3_ratio": 0.0}, "the plates", 0.01, 0.005)
    left = DiscrepancyFinding("unexplained", {}, "the flights depend on position", 0.005, 0.004)
    lens = LensCheck(before_x_noise=9.0, after_x_noise=1.0, kappa_per_m=-0.1, kappa_std_per_m=0.01, signature=True)
    out = lens_findings([harm, left], lens)
    assert [f.effect for f in out] == ["unexplained"]
    assert "structure_harmonics (the plates)" in out[0].where and "depend on position" in out[0].where
    assert out[0].details["not_claimed"] == ["structure_harmonics"]
    assert (out[0].deviation_before, out[0].deviation_after) == (0.01, 0.004)
    no_lens = LensCheck(before_x_noise=9.0, after_x_noise=3.0, kappa_per_m=-0.1, kappa_std_per_m=0.01,
                        signature=False)
    assert lens_findings([harm, left], no_lens) == [harm, left]
