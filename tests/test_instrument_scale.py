"""The image scale's error is the instrument's, never physics (issue 38; vibro_discrepancy.instrument_scale).

A scale camera.mm_per_px off by e makes the flights fall at g (1 + e). With rig.yaml's scale sigma (vibro init
writes camera.mm_per_px_rel_std) the analysis takes a gravity change within 3 combined sigmas as the scale's,
so a drag is found as itself and no tilt or second drag is claimed; a real tilt, far beyond what the scale
allows, is still found. Ground truth: the synthetic rig (tests/discrepancy_cases.py), its track scaled by 1 + e.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from discrepancy_cases import make_case

from vibro_discrepancy.engine import run_discrepancy
from vibro_discrepancy.instrument_scale import SCALE_SIGMAS

DRAG = {"quadratic_drag": {"coefficient_ns2_per_m2": 5e-4}}
FRAMES = 1500          # ~65 flights: the drag is many sigma above the noise and the floor
SCALE_SIGMA = 0.003    # what vibro init states for a lab's frames (0.1-0.3 %)


def _case(effects: dict, scale_error: float = 0.0, scale_rel_std: float | None = SCALE_SIGMA):
    """make_case's (sections, track, rig) with rig.yaml's camera.mm_per_px_rel_std = ``scale_rel_std``."""
    sections, track, rig, _ = make_case(effects, seed=7, frames=FRAMES, scale_error=scale_error)
    if scale_rel_std is not None:
        rig = replace(rig, camera=replace(rig.camera, mm_per_px_rel_std=scale_rel_std))
    return sections, track, rig


def _effects(doc: dict) -> list[str]:
    return [f["effect"] for f in doc["findings"]]


@pytest.mark.parametrize("scale_error", [-0.005, 0.005])
def test_a_scale_error_within_its_sigma_is_the_instruments_and_the_drag_is_found_alone(scale_error):
    sections, track, rig = _case(DRAG, scale_error)
    doc = run_discrepancy(sections, track, rig).document
    scale = doc["instrument_scale"]
    assert scale["absorbed"]
    # the estimate finds the error it was given, within its own sigma x 3 and a DIC-bias allowance of 0.05 %
    assert abs(scale["relative_change"] - scale_error) <= 3 * scale["relative_change_std"] + 5e-4
    assert _effects(doc) == ["quadratic_drag"]
    drag = doc["findings"][0]["parameters"]["coefficient_ns2_per_m2"]
    # the drag coefficient is a force per speed^2: a scale error e scales it by (1 + e)^-1 at most (m a / v^2)
    assert drag == pytest.approx(5e-4, rel=abs(scale_error) + 0.05)


def test_without_a_scale_sigma_nothing_is_taken_as_the_scale():
    sections, track, rig = _case(DRAG, 0.005, scale_rel_std=None)
    doc = run_discrepancy(sections, track, rig).document
    assert "instrument_scale" not in doc
    # the 0.5 % then shows as a gravity change the flight terms must take (a claim the scale sigma prevents)
    assert set(_effects(doc)) - {"quadratic_drag"}


def test_a_real_tilt_is_far_beyond_the_scale_and_still_found():
    tilt_deg = 20.0  # g (1 - cos) = 6 % of g: 20 scale sigmas
    sections, track, rig = _case({"gravity_tilt": {"tilt_deg": tilt_deg}})
    doc = run_discrepancy(sections, track, rig).document
    assert not doc["instrument_scale"]["absorbed"]
    tilt = next(f for f in doc["findings"] if f["effect"] == "gravity_tilt")
    # the scale's sigma on the tilt: d(cos) = 3 sigma_s -> d(tilt) = 3 sigma_s / sin(tilt)
    allowance_deg = math.degrees(SCALE_SIGMAS * SCALE_SIGMA / math.sin(math.radians(tilt_deg)))
    assert abs(tilt["parameters"]["tilt_deg"] - tilt_deg) <= allowance_deg


def test_the_scales_share_of_every_flights_friction_is_taken_out():
    """Eq. 17 measures each flight's friction against the nominal g; with the scale off by e the flights fall at
    g (1 + e), so every friction holds m g e (0.5 % of the weight here, five times the friction floor): taken out
    where the scale was taken as the instrument's, the Eq. 17 value kept beside."""
    from vibro_discrepancy.reidentify import reidentification
    from vibro_model.assemble import apply_reidentification
    from vibro_model.results import ResultsDocument

    e = 0.005
    sections, track, rig = _case({}, e)
    doc = ResultsDocument.from_dict(sections)
    run = run_discrepancy(doc, track, rig)
    assert run.document["instrument_scale"]["absorbed"] and run.document["findings"] == []
    final = apply_reidentification(doc, reidentification(run.result.findings, run))
    weight = rig.ball.mass_kg * 9.81
    free = [f for f in final.flights if f.friction_n is not None]
    before = np.array([f.friction_paper_n for f in free])
    after = np.array([f.friction_n for f in free])
    sd = np.median([f.friction_std_n for f in free])
    # the premise: every Eq. 17 friction is -m g e (the flights fall faster than g), within a flight's sigma
    assert np.median(before) == pytest.approx(-weight * e, abs=3 * sd / np.sqrt(len(free)) + 0.1 * weight * e)
    # taken out: the synthetic rig has no friction
    assert abs(np.median(after)) < 3 * sd / np.sqrt(len(free)) + 0.1 * weight * e
    assert final.sections["friction_model"]["friction_method"] == "instrument_scale"
