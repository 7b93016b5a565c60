"""The discrepancy estimator: baseline -> locate -> explain -> model and show -> what is left.

Shaped like PySINDy: a candidate library (:class:`~.library.CandidateLibrary`) x a selection
(:class:`~.select.StagewiseSelector`) -> a fitted model. ``DiscrepancyEstimator(library, selector)
.fit(measured)`` takes the measurement (:class:`~.data.Measured`: the identification as domain-model types,
the DIC track and the rig, SI) and gives a :class:`DiscrepancyRun`: the typed result
(:class:`vibro_model.results.Discrepancy` with one :class:`~vibro_model.results.DiscrepancyFinding` per
finding, whose ``to_dict()`` is the contract's ``discrepancy`` block: baseline_deviation, findings[{effect,
parameters, where, deviation_before, deviation_after}], final_deviation, plus extras: the paper's D,
parameter uncertainties, the noise floors, the one-step errors before/after, the location of the
baseline's mismatch, every tested candidate with its statistic) and the fitted models for figures and
re-identification. :func:`run_discrepancy` does both steps for ``vibro analyze`` and the ``discrepancy``
node (a results document, the track, the rig).

Two deviations, both on the paper's Eq. 18 scale (a fraction of the measured displacement):

- D_r, the restarted deviation (``baseline_deviation``, ``final_deviation`` and each finding's
  ``deviation_before``/``deviation_after``): every fitted flight simulated with vibro_sim's exact COR
  model from the measured state after the impact that opens it (:func:`.runs.restarted_run`). A real rig
  gives every impact its own COR; restarting after each impact keeps that scatter from accumulating,
  so D_r measures the model (flight law, structure motion), not the chaos: it falls to the noise floor
  (sigma / RMS of the ball displacement) once the model is right, whatever the COR scatter.
- D, the paper's free-running deviation (``paper_baseline_deviation``, ``paper_final_deviation``,
  ``paper_deviation_before/after``): simulated once from the measured state after the first impact
  that opens a fitted flight to the end of the track (:func:`.runs.full_run`). With per-impact COR scatter
  the replay drifts from the record within a few impacts and D stays at a few % for any model.

A COR law is judged by the per-impact CORs instead (D_r replays the measured post-impact velocities):
``cor_variance_share``, the share of the COR variance beyond the measurement noise the law explains.
The baseline: constant COR = the mean measured one, gravity only, pure sine structure, vertical. The
findings are added in order (structure, flight terms, COR law); before/after are the models
without/with each. What the final model still leaves systematically (:mod:`.systematic`) is reported as
``unexplained``; when that holds a structure tone that passes its test (:mod:`.tone`), the tone is
modelled (the final model's structure fit includes it, so the re-identification uses it) and the
``unexplained`` entry's before/after are the models without/with it. When it holds a shape vibro can
parametrise (:mod:`.shape_model`: a position-dependent flight force, a COR alternating with the impact parity),
the shape is fitted and simulated: the finding stays ``unexplained`` without parameters and carries
``shape_model`` (the deviation with it: D_r for the force, D_i for the parity, which D_r cannot see), and an
accepted shape model (its D fell) is the final model, on the catalogue terms the data still need beside it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from vibro_discrepancy.data import Measured, difference_sigma, measurement_of
from vibro_discrepancy.fitting import FlightModelFit, StructureModelFit, fit_flights, fit_structure_harmonics
from vibro_discrepancy.instrument_scale import scale_from_flights
from vibro_discrepancy.library import FLIGHT_TERMS, UNEXPLAINED, CandidateLibrary, FlightTerm, vertical_gravity_mps2
from vibro_discrepancy.locate import cor_law_where, flight_term_where, locate, structure_words
from vibro_discrepancy.model import FittedModel, fit_model
from vibro_discrepancy.onestep import OneStep, one_step
from vibro_discrepancy.optics import lens_check, lens_findings
from vibro_discrepancy.runs import FullRun, full_run, restarted_run
from vibro_discrepancy.select import UNEXPLAINED_RATIO, StageResult, StagewiseSelector, law_variance_share
from vibro_discrepancy.shape import ShapeCheck, check_flight_shape
from vibro_discrepancy.shape_model import (
    DECAYS_MM,
    LABELS,
    PARITY_KIND,
    POSITION_KIND,
    ParityFit,
    PositionFit,
    TermTest,
    cor_share,
    fit_cor_parity,
    impact_restarted_run,
    parity_model,
    parity_parameters,
    parity_words,
    position_form_check,
    position_model,
    position_parameters,
    position_with_terms,
    position_words,
)
from vibro_discrepancy.systematic import Mismatch, contact_scatter, systematic_mismatch
from vibro_discrepancy.tone import TONE_EFFECT, ToneDecision, model_structure_tone
from vibro_io.dictrack import DicTrack
from vibro_io.rig import RigConfig
from vibro_model.codec import json_number, json_value
from vibro_model.results import Discrepancy, DiscrepancyFinding, ResultsDocument
from vibro_model.tail_probability import chi2_sf
from vibro_model.units import m_to_mm

#: the label of the model step that replays the plates' measured motion (a located plate drift)
PLATE_MOTION = "plate_motion"

log = logging.getLogger(__name__)


# ---------------------------------------------------------------- noise floors and the chain of models
@dataclass(frozen=True)
class NoiseFloors:
    """White-noise floors estimated from the data: ball and structure per frame (m), COR (median cor_std)."""

    ball_m: float
    structure_m: float
    cor: float

    def to_dict(self) -> dict:
        return {"ball_mm_per_frame": m_to_mm(self.ball_m), "structure_mm_per_frame": m_to_mm(self.structure_m),
                "cor": self.cor}


def noise_floors(meas: Measured) -> NoiseFloors:
    """Ball: 3rd differences within the flights (5th over the whole track if that fails); structure: 5th
    differences of its track; COR: the median of the identified COR stds' noise share (``Impact.cor_std_noise``; 0
    without any)."""
    ball = difference_sigma([(f.t_s, f.y_m) for f in meas.flights], 3)
    if not math.isfinite(ball) or ball <= 0:
        ball = difference_sigma([(meas.t_s, meas.ball_m)], 5)
    stds = [noise for i in meas.impacts if (noise := i.cor_std_noise or 0.0) > 0]
    return NoiseFloors(ball, difference_sigma([(meas.t_s, meas.structure_m)], 5),
                       float(np.median(stds)) if stds else 0.0)


@dataclass(frozen=True)
class ModelStep:
    """One model of the chain: the fitted model, its paper D run, its restarted D_r run, its one-step errors."""

    label: str
    model: FittedModel
    run: FullRun
    restarted: FullRun
    steps: OneStep


def evaluate(meas: Measured, label: str, model: FittedModel, floors: NoiseFloors) -> ModelStep:
    """``model`` replayed both ways (:mod:`.runs`) and stepped one flight/impact ahead (:mod:`.onestep`)."""
    return ModelStep(label, model, full_run(meas, model), restarted_run(meas, model),
                     one_step(meas, model, floors.ball_m))


@dataclass(frozen=True, kw_only=True)
class Explanation:
    """One catalogue effect explained: its ``effect`` name, the ``model`` with it, its contract ``parameters``
    and their ``stds``, ``where`` it shows (words) and the finding's ``extras`` beside the deviations."""

    effect: str
    model: FittedModel
    parameters: dict
    stds: dict | None
    where: str
    extras: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class FindingChain:
    """The models in the order the findings are added (structure, flight terms, COR law, then the located
    mismatches modelled), each finding with D_r (and the paper's D, the one-step errors) of the model without
    and with it. Immutable: every stage returns a new chain."""

    meas: Measured
    floors: NoiseFloors
    steps: tuple[ModelStep, ...]
    findings: tuple[DiscrepancyFinding, ...] = ()

    @property
    def baseline(self) -> ModelStep:
        return self.steps[0]

    @property
    def current(self) -> ModelStep:
        return self.steps[-1]

    def explained(self, e: Explanation) -> FindingChain:
        """A new chain: ``e``'s model evaluated as the final model, ``e``'s finding (without/with it) added."""
        before, after = self.current, evaluate(self.meas, e.effect, e.model, self.floors)
        details = {"paper_deviation_before": before.run.deviation, "paper_deviation_after": after.run.deviation,
                   "one_step_before": before.steps.summary(), "one_step_after": after.steps.summary(),
                   **e.extras}
        found = finding(e.effect, e.parameters, e.where, before.restarted, after.restarted, e.stds, details)
        return replace(self, steps=self.steps + (after,), findings=self.findings + (found,))

    def with_model(self, step: ModelStep) -> FindingChain:
        """A new chain ending on ``step``, a model without a finding of its own."""
        return replace(self, steps=self.steps + (step,))

    def with_findings(self, findings: Iterable[DiscrepancyFinding]) -> FindingChain:
        """A new chain with the (annotated) ``findings`` in place of its own."""
        return replace(self, findings=tuple(findings))


def finding(effect: str, params: Mapping[str, Any], where: str, before: FullRun, after: FullRun,
            stds: Mapping[str, Any] | None, details: Mapping[str, Any]) -> DiscrepancyFinding:
    """The typed finding, plain JSON values inside (an unknown number is None)."""
    return DiscrepancyFinding(effect, json_value(dict(params)), where, json_number(before.deviation),
                              json_number(after.deviation), None if stds is None else json_value(dict(stds)),
                              json_value(dict(details)))


def annotated(f: DiscrepancyFinding, where: str, extra: Mapping[str, Any]) -> DiscrepancyFinding:
    """``f`` with ``where`` and ``extra`` added to its details."""
    return replace(f, where=where, details={**(f.details or {}), **json_value(dict(extra))})


# ---------------------------------------------------------------- select: library x selector
@dataclass(frozen=True, kw_only=True)
class Selection:
    """What the stage-wise selection chose from the library: the structure fit and its stage, the flight fit
    and its stage (None: a stage not run), the COR law's kind ("none": the constant baseline) and its stage."""

    structure: StructureModelFit
    structure_stage: StageResult | None
    flights: FlightModelFit
    flight_stage: StageResult | None
    cor_kind: str
    cor_stage: StageResult

    def stages(self) -> dict:
        """Per stage run: the chosen terms, the residual in noise floors, every candidate tested."""
        return stages_section(self.structure_stage, self.flight_stage, self.cor_stage)


def select_terms(meas: Measured, floors: NoiseFloors, library: CandidateLibrary, selector: StagewiseSelector
                 ) -> Selection:
    """The selection's three stages in turn: structure, flights, then the COR law on the impacts measured under
    the chosen structure and flights."""
    s_fit, s_stage = selector.structure(meas, floors.structure_m, library)
    f_fit, f_stage = selector.flights(meas, floors.ball_m, library)
    pre_cor = fit_model(meas, structure=s_fit, flights=f_fit)
    kind, c_stage = selector.cor(pre_cor.impacts, floors.cor, library)
    return Selection(structure=s_fit, structure_stage=s_stage, flights=f_fit, flight_stage=f_stage, cor_kind=kind,
                     cor_stage=c_stage)


def pure_sine(meas: Measured) -> StructureModelFit:
    """The baseline's structure: the drive's sine alone, fitted to the structure track."""
    return fit_structure_harmonics(meas.t_s, meas.structure_m, meas.frequency_hz, (1,))


# ---------------------------------------------------------------- explain: one stage at a time
def explain_structure(chain: FindingChain, sel: Selection, sine: StructureModelFit) -> FindingChain:
    """structure_harmonics when the selection chose harmonics: ratios to the fundamental, their stds; where the
    pure ``sine`` misses the track."""
    stage, s_fit = sel.structure_stage, sel.structure
    if stage is None or not stage.chosen:
        return chain
    meas, floors = chain.meas, chain.floors
    mot = s_fit.motion()
    amps = s_fit.harmonic_amplitudes()
    sd = s_fit.sigma * math.sqrt(2.0 / s_fit.n_points) / max(mot.amplitude_m, 1e-12)
    where = (structure_words(sine.residual, meas.t_s, floors.structure_m, sine.frequency_hz) + "; "
             + locate(chain.current.steps, floors.cor, stages=("impacts",))["text"])
    return chain.explained(Explanation(
        effect="structure_harmonics", model=fit_model(meas, structure=s_fit, flights=fit_flights(meas)),
        parameters={"h2_ratio": float(mot.h2_ratio), "h3_ratio": float(mot.h3_ratio)},
        stds={"h2_ratio": sd if 2 in amps else None, "h3_ratio": sd if 3 in amps else None}, where=where,
        extras={"phases_rad": {"h2_phase_rad": float(mot.h2_phase_rad), "h3_phase_rad": float(mot.h3_phase_rad)}}))


def explain_flights(chain: FindingChain, sel: Selection, terms: tuple[FlightTerm, ...]) -> FindingChain:
    """The chosen flight terms, in the order of what each explains alone (the chain's D); parameters and
    their uncertainties from the fit with all chosen terms."""
    stage, f_fit = sel.flight_stage, sel.flights
    if stage is None or not stage.chosen:
        return chain
    meas, floors = chain.meas, chain.floors
    single = {d.label: d.statistic for d in stage.decisions}
    chosen = sorted((t for t in terms if t.effect in stage.chosen), key=lambda t: -single.get(t.effect, 0.0))
    for j, term in enumerate(chosen):
        fset = f_fit if j == len(chosen) - 1 else fit_flights(meas, tuple(chosen[:j + 1]))
        model = fit_model(meas, structure=chain.current.model.structure, flights=fset)
        idx = f_fit.names.index(term.effect)
        params, stds = term.contract_parameters(float(f_fit.coefs[idx]), float(math.sqrt(f_fit.cov[idx, idx])),
                                                meas.mass_kg, meas.g_mps2, meas.axis_tilt_deg)
        where = flight_term_where(meas, chain.current.steps, model, term, floors.cor)
        extras = scale_could_explain(term, float(f_fit.coefs[idx]), meas)
        if extras:
            where += "; " + extras["scale_note"]
        tilt = declared_tilt_words(term, params, meas)
        if tilt:
            extras = {**extras, **tilt}
            where += "; " + tilt["tilt_note"]
        chain = chain.explained(Explanation(effect=term.effect, model=model, parameters=params, stds=stds,
                                            where=where, extras=extras))
    return chain


#: a gravity change within this many of the scale's relative sigmas (rig.yaml camera.mm_per_px_rel_std) is as
#: much a scale error as a tilt
SCALE_SIGMAS = 3.0


def scale_could_explain(term: FlightTerm, coef_mps2: float, meas: Measured) -> dict[str, Any]:
    """For ``gravity_tilt``: when the gravity change it fits (``coef_mps2``, m/s^2) lies within
    :data:`SCALE_SIGMAS` of rig.yaml's scale uncertainty (``camera.mm_per_px_rel_std``), the finding says that a
    scale error would give it as well (a scale off by x scales every flight's acceleration by 1 + x, which is
    what a tilt does to gravity: the flights cannot tell them apart); the tilt is then not a claim. Empty
    otherwise (another term, or no scale uncertainty given)."""
    if term.effect != "gravity_tilt" or meas.scale_rel_std <= 0 or abs(meas.g_mps2) < 1e-9:
        return {}   # a scale error scales the gravity along the axis: with none (horizontal) it makes no tilt
    rel = coef_mps2 / meas.g_mps2
    if abs(rel) > SCALE_SIGMAS * meas.scale_rel_std:
        return {}
    return {"scale_could_explain": True,
            "scale_note": (f"or the scale camera.mm_per_px off by {-100 * rel:+.2f} %, within {SCALE_SIGMAS:g} of its "
                           f"sigmas ({100 * meas.scale_rel_std:.2f} %, rig.yaml mm_per_px_rel_std): the flights "
                           "cannot tell a tilt from a scale error, so no tilt is claimed")}


def declared_tilt_words(term: FlightTerm, params: Mapping[str, float], meas: Measured) -> dict[str, Any]:
    """For ``gravity_tilt`` on a rig declared tilted (rig.yaml ``setup.axis_tilt_deg`` > 0, i.e. ``meas.g_mps2`` <
    g): the finding's ``tilt_deg`` is the axis' TOTAL tilt from vertical; this says the declared part and the
    undeclared rest ({"declared_axis_tilt_deg", "undeclared_tilt_deg", "tilt_note"}). Empty otherwise."""
    declared = float(meas.axis_tilt_deg)
    if term.effect != "gravity_tilt" or declared <= 0.0:
        return {}
    total = float(params["tilt_deg"])
    g = vertical_gravity_mps2(meas.g_mps2, declared)
    return {"declared_axis_tilt_deg": declared, "undeclared_tilt_deg": total - declared,
            "tilt_note": (f"tilt_deg is the axis' total tilt from vertical, {total:.2f} deg: {total - declared:+.2f} "
                          f"deg beyond the declared setup.axis_tilt_deg {declared:g} deg (gravity along the axis "
                          f"{g * math.cos(math.radians(total)):.3f} m/s^2, not the declared {meas.g_mps2:.3f})")}


def explain_cor(chain: FindingChain, sel: Selection, library: CandidateLibrary) -> FindingChain:
    """The chosen COR law (``sel.cor_kind``, "none": the constant baseline stays) and the share of the COR
    variance beyond noise it explains."""
    kind, stage = sel.cor_kind, sel.cor_stage
    if kind == "none":
        return chain
    meas, cur = chain.meas, chain.current.model
    model = fit_model(meas, structure=cur.structure, flights=cur.flights, cor_kind=kind)
    params, stds = library.impact_term(kind).contract_parameters(model.cor.coefs, model.cor.cov)
    extras: dict[str, Any] = {"cor_variance_share": law_variance_share(model.impacts, model.cor)}
    if stage.alternatives:
        extras["alternatives"] = list(stage.alternatives)
    if stage.notes:
        extras["note"] = "; ".join(stage.notes)
    where = cor_law_where(meas, chain.current.steps, model, chain.floors.cor)
    return chain.explained(Explanation(effect=kind, model=model, parameters=params, stds=stds, where=where,
                                       extras=extras))


def flight_shape(chain: FindingChain, f_stage: StageResult | None) -> ShapeCheck | None:
    """The flights' residual in the catalogue's coordinates (:mod:`.shape`) after the chosen flight terms,
    when any was chosen or the flights keep a mismatch (None: not checked, or the check failed)."""
    if f_stage is None or not (f_stage.chosen or f_stage.unexplained):
        return None
    model = chain.current.model
    try:
        return check_flight_shape(chain.meas, model.flights, model.motion, chain.floors.ball_m)
    except (ValueError, np.linalg.LinAlgError) as exc:   # a degenerate design: no test, said so
        log.warning("flight shape check failed: %s", exc)
        return None


def note_flight_shape(chain: FindingChain, shape: ShapeCheck | None) -> FindingChain:
    """Every flight finding carries the shape check (``details.shape_check``) and, when the residual is
    structured, says that it does not fit it."""
    if shape is None:
        return chain
    flight_effects = {t.effect for t in FLIGHT_TERMS}

    def noted(f: DiscrepancyFinding) -> DiscrepancyFinding:
        if f.effect not in flight_effects:
            return f
        extra: dict[str, Any] = {"shape_check": shape.to_dict()}
        where = f.where
        if shape.structured:
            extra["fits_residual_shape"] = False
            where = (f"{where}; lowers the deviation but does not fit the residual's shape: the residual left "
                     "depends on the ball's position (see unexplained)")
        return annotated(f, where, extra)

    return chain.with_findings(noted(f) for f in chain.findings)


# ---------------------------------------------------------------- what the catalogue model leaves
@dataclass(frozen=True)
class Systematic:
    """What the catalogue model leaves systematically (:mod:`.systematic`): the ``patterns`` (under the final
    model), the structure tone's decision (:mod:`.tone`) and the model step before a modelled tone (None: no tone
    modelled)."""

    patterns: list[Mismatch]
    tone: ToneDecision
    before_tone: ModelStep | None = None
    before_plates: ModelStep | None = None   # the step before the plates' measured motion was replayed

    @property
    def before(self) -> ModelStep | None:
        """The model step before the first located mismatch that was modelled (a tone, the plates' motion)."""
        return self.before_tone if self.before_tone is not None else self.before_plates


def with_structure_tone(chain: FindingChain, tone: ToneDecision) -> FindingChain:
    """The chain with a modelled tone's model as its final model: its structure fit replaced by the one with the
    tone (flights and COR law kind kept, the COR law refitted on the corrected impacts)."""
    cur = chain.current.model
    model = fit_model(chain.meas, structure=tone.model.fit, flights=cur.flights, cor_kind=cur.cor.kind)
    return chain.with_model(evaluate(chain.meas, TONE_EFFECT, model, chain.floors))


def with_plate_motion(chain: FindingChain) -> FindingChain:
    """The chain with its final model replayed with the plates' measured motion (:func:`.model.moved_plates`)."""
    model = replace(chain.current.model, with_plates=True)
    return chain.with_model(evaluate(chain.meas, PLATE_MOTION, model, chain.floors))


def creeping_plates_located(meas: Measured, patterns: list[Mismatch]) -> list[str]:
    """The plates whose contact level the systematic analysis located as drifting (``contact_level`` patterns) and
    whose creep the identification measured and took into the CORs (results.json ``plate_motion``)."""
    return sorted({p.plate for p in patterns if p.series == "contact_level" and p.plate in meas.plate_creeps
                   and not p.common_mode})


def find_systematic(chain: FindingChain) -> tuple[FindingChain, Systematic]:
    """The systematic patterns the chain's model leaves; a located tone that passes its test is modelled (the
    chain then ends on the model with it) and the contact levels and CORs are tested again under it. A located
    drift of a plate's contact level whose creep the identification measured is then replayed (the chain ends on
    the model with the plates' measured motion); the patterns stay those located."""
    meas, floors = chain.meas, chain.floors
    fps = 1.0 / float(np.median(np.diff(meas.t_s)))
    patterns = systematic_mismatch(meas, chain.current.model, floors.structure_m, floors.ball_m, fps)
    tone = model_structure_tone(meas, chain.current.model.structure, patterns, fps)
    before_tone = None
    if tone.model is not None:
        before_tone = chain.current
        chain = with_structure_tone(chain, tone)
        patterns = systematic_mismatch(meas, chain.current.model, floors.structure_m, floors.ball_m, fps,
                                       structure=[p for p in patterns if p.series == "structure"])
    before_plates = None
    if creeping_plates_located(meas, patterns):
        before_plates = chain.current
        chain = with_plate_motion(chain)
    return chain, Systematic(patterns, tone, before_tone, before_plates)


def leftover_words(chain: FindingChain, sine: StructureModelFit, sel: Selection, patterns: list[Mismatch],
                   shape: ShapeCheck | None) -> list[str]:
    """What the final model leaves that is not noise, in words: a stage's residual above UNEXPLAINED_RATIO x its
    noise floor, the systematic ``patterns``, a structured flight ``shape`` first; empty when nothing is left.
    A drive that did not hold still (a ``drive`` pattern) is not physics the model left out: results.json's
    ``drive`` section and its warning say what the drive did, and no finding claims it."""
    meas, floors, cur = chain.meas, chain.floors, chain.current
    s_stage, f_stage = sel.structure_stage, sel.flight_stage
    final_loc = locate(cur.steps, floors.cor)
    flights_words = final_loc["words"][0] if final_loc["words"] else "flights"
    words = []
    s_ratio = s_stage.residual_ratio if s_stage is not None else sine.sigma / floors.structure_m
    if s_ratio > UNEXPLAINED_RATIO and not any(p.series == "structure" for p in patterns):
        words.append(structure_words(cur.model.structure.residual, meas.t_s, floors.structure_m,
                                     sine.frequency_hz).replace("the pure sine misses", "the model misses"))
    if f_stage is not None and f_stage.unexplained:
        words.append(flights_words)
    elif f_stage is None:
        flights = cur.model.flights
        if math.sqrt(flights.sse / max(flights.n_points, 1)) / floors.ball_m > 1.5:
            words.append(flights_words)
    words += [p.words() for p in patterns if p.shape != "drive" and not p.common_mode]
    if shape is not None and shape.structured:
        words.insert(0, shape.words())
    return words


def unexplained_finding(chain: FindingChain, sine: StructureModelFit, sel: Selection, left: Systematic,
                        shape: ShapeCheck | None) -> DiscrepancyFinding | None:
    """What the final model leaves that is not noise (:func:`leftover_words`), or None; random COR scatter is
    not. A modelled structure tone (``left.tone.model``) gives the finding its parameters, and its D_r and the
    paper's D before/after are the models without/with it; else both are the final model."""
    words = leftover_words(chain, sine, sel, left.patterns, shape)
    if not words:
        return None
    cur = chain.current
    before = cur if left.before is None else left.before
    details: dict[str, Any] = {"paper_deviation_before": before.run.deviation,
                               "paper_deviation_after": cur.run.deviation,
                               "mismatches": [p.to_dict() for p in left.patterns]}
    if shape is not None and shape.structured:
        details["shape"] = shape.to_dict()
    params: dict[str, Any] = {}
    stds = None
    tone = left.tone
    if tone.tests and tone.model is None:   # located, tested, not modelled: why
        details["tone_tests"] = tone.to_dict()
    if tone.model is not None:
        params, stds = tone.model.parameters(), tone.model.parameter_stds()
        details["model"] = tone.model.to_dict()
        details["one_step_before"] = before.steps.summary()
        details["one_step_after"] = cur.steps.summary()
        words.append(tone.model.words())
    if left.before_plates is not None:
        details["plate_motion"] = plate_motion_details(chain.meas, left)
        words.append(plate_motion_words(chain.meas, left))
    return finding(UNEXPLAINED, params, "; ".join(words), before.restarted, cur.restarted, stds, details)


def plate_motion_details(meas: Measured, left: Systematic) -> dict[str, Any]:
    """The finding's record of the plates' measured motion, replayed: which plates and their mean rate (um/s, the
    creep's travel over the recording / its span); the finding's deviations are without and with it."""
    t0, t1 = float(meas.t_s[0]), float(meas.t_s[-1])
    span = t1 - t0
    rates = {p: (c.level_um(t1) - c.level_um(t0)) / span
             for p, c in meas.plate_creeps.items() if p in creeping_plates_located(meas, left.patterns)}
    return {"plates": sorted(rates), "mean_rate_um_per_s": {p: json_number(r) for p, r in rates.items()},
            "span_s": json_number(span), "source": "results.json plate_motion (the identification's contact levels)"}


def plate_motion_words(meas: Measured, left: Systematic) -> str:
    """The replayed plate motion, in words."""
    plates = creeping_plates_located(meas, left.patterns)
    return ("modelled: the " + " and ".join(plates) + " plate's measured creep replayed in the simulation (the "
            "identification's contact levels, results.json plate_motion)")


#: COR patterns in the catalogue COR laws' own coordinates and beside them: left after a chosen law, the law
#: does not fit the COR's shape (a trend or step in time is another effect on top of a law that fits)
COR_LAW_SHAPES = ("plate", "speed", "parity")


def cor_shape_left(chain: FindingChain, patterns: list[Mismatch]) -> list[Mismatch]:
    """The COR patterns (:mod:`.systematic`, tested against the COR scatter after the final COR law) that
    the chosen COR law leaves in its coordinates (``COR_LAW_SHAPES``); empty when no COR law was chosen."""
    left = [p for p in patterns if p.series == "cor" and p.shape in COR_LAW_SHAPES]
    laws = set(CandidateLibrary.cor_terms)
    return left if any(f.effect in laws for f in chain.findings) else []


def note_cor_shape_left(chain: FindingChain, left: list[Mismatch]) -> FindingChain:
    """The COR law's finding, when it leaves COR patterns in its coordinates (``left``), says that it does not
    fit the COR's shape (``fits_residual_shape`` false, ``details.cor_shape_left``)."""
    if not left:
        return chain
    laws = set(CandidateLibrary.cor_terms)
    extra = {"fits_residual_shape": False, "cor_shape_left": [p.to_dict() for p in left]}

    def noted(f: DiscrepancyFinding) -> DiscrepancyFinding:
        if f.effect not in laws:
            return f
        where = (f"{f.where}; lowers the COR scatter but does not fit the COR's shape: "
                 + "; ".join(p.what() for p in left) + " (see unexplained)")
        return annotated(f, where, extra)

    return chain.with_findings(noted(f) for f in chain.findings)


def order_findings(findings: Sequence[DiscrepancyFinding], leftover: DiscrepancyFinding | None,
                   shape: ShapeCheck | None, cor_left: list[Mismatch] | None = None) -> list[DiscrepancyFinding]:
    """The findings in the order they are reported: the chain's, then ``unexplained``; when the flight
    finding leaves a structured residual (``shape``) or the COR law a shaped COR residual (``cor_left``),
    ``unexplained`` comes first and the catalogue findings below it (a model that lowers the deviation
    without fitting the shape is not claimed on top)."""
    if leftover is None:
        return list(findings)
    if (shape is not None and shape.structured) or cor_left:
        return [leftover] + list(findings)
    return list(findings) + [leftover]


# ---------------------------------------------------------------- a located shape, modelled
@dataclass(kw_only=True)
class ShapeStep:
    """A located shape modelled (:mod:`.shape_model`): the model steps without and with it, the deviation that
    judges it (``measure``: D_r for a flight force, D_i for a COR law) before/after, accepted when it falls."""

    kind: str
    form: str
    parameters: dict
    stds: dict
    before: ModelStep
    after: ModelStep
    measure: str
    value_before: float | None
    value_after: float | None
    sits_on: list[str]
    not_kept: list[str]
    extras: dict
    absorbs: list[Mismatch] = field(default_factory=list)
    rejected: str | None = None      # why the fitted form is not the residual's shape (then not kept)

    @property
    def lowered(self) -> bool:
        b, a = self.value_before, self.value_after
        return a is not None and b is not None and math.isfinite(a) and math.isfinite(b) and a < b

    @property
    def accepted(self) -> bool:
        return self.rejected is None and self.lowered

    def clause(self) -> str:
        """The clause the ``unexplained`` finding's ``where`` ends with."""
        b, a = _pct(self.value_before), _pct(self.value_after)
        how = (" (D_i: each flight restarted from the measured state before the impact that opens it, that "
               "impact's COR from the model; D_r replays the measured CORs and cannot see a COR law)"
               if self.measure == "D_i" else "")
        if self.accepted:
            return f"modelled as {self.form}: D falls from {b} to {a}{how}"
        if self.rejected:
            return (f"fitted as {self.form} (D {b} -> {a}{how}) but not kept: that form is not the residual's "
                    f"shape ({self.rejected})")
        return f"modelled as {self.form}: D does not fall ({b} -> {a}){how}, so the model is not kept"

    def to_dict(self) -> dict:
        b, a = self.before, self.after
        dev = {"measure": self.measure, "before": self.value_before, "after": self.value_after,
               "restarted_before": b.restarted.deviation, "restarted_after": a.restarted.deviation,
               "paper_before": b.run.deviation, "paper_after": a.run.deviation}
        return {"kind": self.kind, "form": self.form, "parameters": self.parameters, "parameters_std": self.stds,
                "sits_on": self.sits_on, "not_kept": self.not_kept, "deviation": dev, "accepted": self.accepted,
                "rejected": self.rejected, "model": a.model.label(), **self.extras}


def _pct(d: float | None) -> str:
    return "n/a" if d is None else f"{100 * d:.3g} %"


def _position_extras(meas: Measured, floors: NoiseFloors, fit: PositionFit, tests: list[TermTest], form: dict,
                     catalogue: FlightModelFit) -> dict:
    """The position shape model's details: the catalogue terms' tests beside it, its form check, the kept terms'
    contract parameters and the fit (sum of squares mm^2, the chi^2 against the ``catalogue`` fit of the kept
    terms alone)."""
    chi = max(catalogue.sse - fit.sse, 0.0) / floors.ball_m ** 2
    term_params = []
    for t, c, sd in zip(fit.terms, fit.flights.coefs, fit.term_stds):
        tp, ts = t.contract_parameters(float(c), float(sd), meas.mass_kg, fit.flights.g_mps2, meas.axis_tilt_deg)
        term_params.append({"effect": t.effect, "parameters": tp, "parameters_std": ts})
    return {"term_tests": [t.to_dict() for t in tests], "form_check": form, "term_parameters": term_params,
            "fit": {"sse_mm2": fit.sse * 1e6, "dof": fit.dof, "noise_floor_mm": floors.ball_m * 1e3,
                    "residual_x_noise": math.sqrt(fit.sse / max(fit.flights.n_points, 1)) / floors.ball_m,
                    "chi2_vs_catalogue": chi, "chi2_dof": 2, "p_value": chi2_sf(chi, 2),
                    "decay_at_grid_end": fit.at_grid_end, "decay_search_mm": [DECAYS_MM[0], DECAYS_MM[-1]]}}


def position_shape_step(chain: FindingChain, shape: ShapeCheck | None) -> ShapeStep | None:
    """A force that depends on the ball's distance from the lower plate, when the shape check finds the flights'
    residual beyond the chain's flight terms structured in that coordinate: fitted beside the chain's flight terms
    (each kept only when the data still need it) on top of the chain's current model, and kept only when that
    form is the residual's shape (:func:`position_form_check`); None when the residual is not structured so."""
    if shape is None or not shape.structured or not shape.tests.get("position", {}).get("structured"):
        return None
    meas, floors, before = chain.meas, chain.floors, chain.current
    terms = tuple(before.model.flights.terms)
    try:
        fit, tests = position_with_terms(meas, before.model, terms, floors.ball_m)
        model = position_model(meas, before.model, fit)
        catalogue = fit_flights(meas, fit.terms)
        form = position_form_check(meas, before.model, fit, floors.ball_m)
    except (ValueError, np.linalg.LinAlgError) as exc:
        log.warning("position shape model failed: %s", exc)
        return None
    after = evaluate(meas, LABELS[POSITION_KIND], model, floors)
    params, stds = position_parameters(fit, meas)
    kept = [t.effect for t in fit.terms]
    extras = _position_extras(meas, floors, fit, tests, form, catalogue)
    return ShapeStep(kind=POSITION_KIND, form=position_words(params, stds), parameters=params, stds=stds,
                     before=before, after=after, measure="D_r", value_before=before.restarted.deviation,
                     value_after=after.restarted.deviation, sits_on=kept,
                     not_kept=[t.effect for t in terms if t.effect not in kept], extras=extras,
                     rejected=form["reason"])


def _parity_extras(before: FittedModel, model: FittedModel, pf: ParityFit, d_i: tuple[FullRun, FullRun]) -> dict:
    """The parity shape model's details: the COR laws tested beside it, the share of the COR variance and the COR
    scatter without (``before``)/with it (``model``), the impacts, and why a D_i run (before, after) failed."""
    extras = {"law_tests": pf.tests, "cor_variance_share": {"before": cor_share(before), "after": cor_share(model)},
              "cor_scatter": {"before": math.sqrt(before.cor.sse / max(before.cor.dof, 1)),
                              "after": math.sqrt(pf.fit.sse / max(pf.fit.dof, 1))},
              "n_impacts": int(pf.fit.n)}
    for run, key in zip(d_i, ("before", "after")):
        if run.error:
            extras.setdefault("notes", []).append(f"D_i {key}: {run.error}")
    return extras


def parity_shape_step(chain: FindingChain, patterns: list[Mismatch], library: CandidateLibrary
                      ) -> ShapeStep | None:
    """The COR parity located on a plate (the strongest ``parity`` COR mismatch), fitted on a COR law the data
    support beside it, on top of the chain's current model; judged by D_i; None without such a mismatch."""
    par = [p for p in patterns if p.series == "cor" and p.shape == "parity" and p.plate]
    if not par:
        return None
    meas, floors, before = chain.meas, chain.floors, chain.current
    pf = fit_cor_parity(before.model.impacts, par[0].plate, meas.frequency_hz, ("none",) + tuple(library.cor_terms))
    if pf is None:
        return None
    model = parity_model(meas, before.model, pf)
    after = evaluate(meas, LABELS[PARITY_KIND], model, floors)
    d_b, d_a = impact_restarted_run(meas, before.model), impact_restarted_run(meas, model)
    params, stds = parity_parameters(pf, model.impacts)
    kind = before.model.cor.kind
    sits = [] if pf.base_kind == "none" else [pf.base_kind]
    return ShapeStep(kind=PARITY_KIND, form=parity_words(pf, params, stds), parameters=params, stds=stds,
                     before=before, after=after, measure="D_i", value_before=d_b.deviation, value_after=d_a.deviation,
                     sits_on=sits, not_kept=[kind] if kind != "none" and kind not in sits else [],
                     extras=_parity_extras(before.model, model, pf, (d_b, d_a)), absorbs=[par[0]])


def model_shapes(chain: FindingChain, leftover: DiscrepancyFinding | None, shape: ShapeCheck | None,
                 patterns: list[Mismatch], library: CandidateLibrary) -> tuple[FindingChain, list[ShapeStep]]:
    """When something is left (``leftover``), the located shapes vibro can parametrise, modelled in turn (a
    position force, then a COR parity on top of the model so far); an accepted one becomes the chain's final
    model. Returns the chain and the shapes modelled."""
    if leftover is None:
        return chain, []
    steps = []
    for make in (lambda c: position_shape_step(c, shape), lambda c: parity_shape_step(c, patterns, library)):
        step = make(chain)
        if step is None:
            continue
        steps.append(step)
        if step.accepted:
            chain = chain.with_model(step.after)
    return chain, steps


def shape_model_section(steps: list[ShapeStep]) -> dict:
    """The ``unexplained`` finding's ``shape_model``: the one shape modelled, or both merged (``parts``)."""
    parts = [s.to_dict() for s in steps]
    if len(parts) == 1:
        return parts[0]
    return {"kind": "+".join(p["kind"] for p in parts), "form": "; and ".join(p["form"] for p in parts),
            "parameters": {k: v for p in parts for k, v in p["parameters"].items()},
            "parameters_std": {k: v for p in parts for k, v in p["parameters_std"].items()},
            "deviation": parts[0]["deviation"], "accepted": all(p["accepted"] for p in parts), "parts": parts}


def with_shape_models(leftover: DiscrepancyFinding | None, steps: list[ShapeStep], final: ModelStep
                      ) -> DiscrepancyFinding | None:
    """The ``unexplained`` finding with its shapes modelled (``shape_model``, a clause per shape in ``where``);
    its ``deviation_after`` (and the paper's, the one-step errors after) the final model's D_r when lower."""
    if leftover is None or not steps:
        return leftover
    where = "; ".join([leftover.where] + [s.clause() for s in steps])
    details = {**(leftover.details or {}), "shape_model": json_value(shape_model_section(steps))}
    after = leftover.deviation_after
    d = final.restarted.deviation
    if any(s.accepted for s in steps) and d is not None and after is not None and d < after:
        after = json_number(d)
        details["paper_deviation_after"] = json_number(final.run.deviation)
        details["one_step_after"] = json_value(final.steps.summary())
    return replace(leftover, where=where, deviation_after=after, details=details)


def _not_needed_clause(step: ShapeStep, test: dict | None) -> str:
    """Why a catalogue finding is not in the final model beside the accepted shape ``step`` (its ``test``)."""
    if test is None:
        why = ""
    elif "chi2" in test:
        why = (f" (chi2 = {test['chi2']:.3g}, p = {test['p_value']:.2g}, "
               f"{test['explained_x_noise']:.2f} noise floors)")
    else:
        why = (f" (F = {test['f_statistic']:.3g}, p = {test['p_value']:.2g}, "
               f"explained COR rms {test['explained_rms']:.4f})")
    what = "position-dependent force" if step.kind == POSITION_KIND else "COR parity"
    return (f"; not in the final model: with the {what} of the unexplained finding modelled, the data do not "
            f"need it{why}")


def _under_shape(f: DiscrepancyFinding, step: ShapeStep) -> DiscrepancyFinding:
    """Catalogue finding ``f`` beside the accepted shape ``step``: its test there (``shape_model_test``), its
    values in the final model when kept (``with_shape_model``), or ``in_final_model`` false and why."""
    tests = {t["effect"]: t for t in step.extras.get("term_tests", [])}
    tests.update({t["law"]: t for t in step.extras.get("law_tests", [])})
    extra: dict[str, Any] = {}
    where = f.where
    if f.effect in tests:
        extra["shape_model_test"] = tests[f.effect]
    kept = [t for t in step.extras.get("term_parameters", []) if t["effect"] == f.effect]
    if kept:   # kept beside the shape: its values in the final model
        extra["with_shape_model"] = {k: kept[0][k] for k in ("parameters", "parameters_std")}
    if f.effect in step.not_kept:
        extra["in_final_model"] = False
        where = where + _not_needed_clause(step, tests.get(f.effect))
    return annotated(f, where, extra) if extra else f


def mark_catalogue_under_shapes(chain: FindingChain, steps: list[ShapeStep]) -> FindingChain:
    """A catalogue finding a shape model was fitted beside: the test (``shape_model_test``), and where the data
    do not need it with the shape modelled, ``in_final_model`` false and a clause saying so."""
    findings = chain.findings
    for step in steps:
        if step.accepted:
            findings = tuple(_under_shape(f, step) for f in findings)
    return chain.with_findings(findings)


def not_absorbed(patterns: list[Mismatch], steps: list[ShapeStep]) -> list[Mismatch]:
    """The patterns no accepted shape model absorbed (the contact scatter: after the final COR law)."""
    absorbed = [id(m) for s in steps if s.accepted for m in s.absorbs]
    return [p for p in patterns if id(p) not in absorbed]


# ---------------------------------------------------------------- model and show
def stages_section(*stages: StageResult | None) -> dict:
    """Per stage run: the chosen terms, the residual in noise floors, every candidate tested."""
    return {st.name: {"chosen": list(st.chosen), "residual_x_noise": st.residual_ratio,
                      "unexplained": st.unexplained, "notes": st.notes,
                      "candidates": [d.to_dict() for d in st.decisions]}
            for st in stages if st is not None}


def run_details(chain: FindingChain, location: dict, stages: dict, patterns: list[Mismatch]) -> dict:
    """The block's extras beside the contract keys (see the module docstring)."""
    base, cur = chain.baseline, chain.current
    cor = cur.model.cor
    return {
        "paper_baseline_deviation": base.run.deviation,
        "paper_final_deviation": cur.run.deviation,
        "model": cur.model.label(),
        "replay_start_s": base.run.t_s[0] if base.run.t_s.size else None,
        "noise_floor": chain.floors.to_dict(),
        "cor_scatter": math.sqrt(cor.sse / max(cor.dof, 1)) if cor.n else None,
        "contact_scatter": contact_scatter(cur.model, patterns),
        "one_step": {"baseline": base.steps.summary(), "final": cur.steps.summary()},
        "location": {k: v for k, v in location.items() if k != "words"},
        "stages": stages,
        "notes": list(chain.meas.notes) + [f"{s.label}: {s.run.error}" for s in chain.steps if s.run.error]
        + [f"{s.label} (restarted): {s.restarted.error}" for s in chain.steps if s.restarted.error]
        + [p.words() for p in patterns if p.common_mode],
    }


@dataclass(kw_only=True)
class DiscrepancyRun:
    """The fitted discrepancy model: the typed result (``result``; ``document`` is its contract block) and
    the models and runs behind it, for figures and re-identification."""

    result: Discrepancy
    measured: Measured | None = None
    baseline: FittedModel | None = None
    final: FittedModel | None = None
    baseline_run: FullRun | None = None
    final_run: FullRun | None = None
    baseline_steps: OneStep | None = None
    final_steps: OneStep | None = None
    chain: list[tuple[str, FittedModel, FullRun]] = field(default_factory=list)
    baseline_restarted: FullRun | None = None   # the D_r runs (the block's baseline/final_deviation)
    final_restarted: FullRun | None = None

    @cached_property
    def document(self) -> dict:
        """The contract's ``discrepancy`` block (``result.to_dict()``)."""
        return self.result.to_dict()


def discrepancy_run(chain: FindingChain, findings: list[DiscrepancyFinding], details: dict) -> DiscrepancyRun:
    """The run of a finished chain: the typed result (D_r of its baseline and final model, the ``findings`` in
    their reported order, the block's extras ``details``) and the models and runs behind it."""
    base, cur = chain.baseline, chain.current
    result = Discrepancy(json_number(base.restarted.deviation), findings, json_number(cur.restarted.deviation),
                         json_value(details))
    return DiscrepancyRun(result=result, measured=chain.meas, baseline=base.model, final=cur.model,
                          baseline_run=base.run, final_run=cur.run, baseline_steps=base.steps, final_steps=cur.steps,
                          chain=[(s.label, s.model, s.run) for s in chain.steps], baseline_restarted=base.restarted,
                          final_restarted=cur.restarted)


@dataclass(frozen=True)
class DiscrepancyEstimator:
    """Candidate library x stage-wise selection -> the fitted discrepancy model (module docstring)."""

    library: CandidateLibrary = field(default_factory=CandidateLibrary)
    selector: StagewiseSelector = field(default_factory=StagewiseSelector)

    def fit(self, meas: Measured) -> DiscrepancyRun:
        """The discrepancy model of ``meas``: baseline -> select -> explain -> what is left -> shapes modelled;
        each stage takes the chain the stage before it returned and returns a new one. The image scale's
        share of the flights' gravity is the instrument's (:mod:`.instrument_scale`) before anything is looked for."""
        meas, scale = scale_from_flights(meas)
        floors = noise_floors(meas)
        baseline = evaluate(meas, "baseline", fit_model(meas), floors)
        location = locate(baseline.steps, floors.cor)
        sine = pure_sine(meas)
        selection = select_terms(meas, floors, self.library, self.selector)
        chain = FindingChain(meas, floors, (baseline,))
        chain = explain_structure(chain, selection, sine)
        chain = explain_flights(chain, selection, self.library.flight_terms)
        shape = flight_shape(chain, selection.flight_stage)
        chain = note_flight_shape(chain, shape)
        chain = explain_cor(chain, selection, self.library)
        chain, left = find_systematic(chain)
        leftover = unexplained_finding(chain, sine, selection, left, shape)
        cor_left = cor_shape_left(chain, left.patterns)
        chain = note_cor_shape_left(chain, cor_left)
        chain, shape_steps = model_shapes(chain, leftover, shape, left.patterns, self.library)
        leftover = with_shape_models(leftover, shape_steps, chain.current)
        chain = mark_catalogue_under_shapes(chain, shape_steps)
        details = run_details(chain, location, selection.stages(), not_absorbed(left.patterns, shape_steps))
        if scale is not None:
            details["instrument_scale"] = scale.to_dict()
        flights = selection.flight_stage
        lens = lens_check(meas, flights.residual_ratio if flights is not None else math.inf)
        if lens is not None:
            details["lens_check"] = lens.to_dict()
        findings = lens_findings(order_findings(chain.findings, leftover, shape, cor_left), lens)
        return discrepancy_run(chain, findings, details)


# ---------------------------------------------------------------- entry points
def run_discrepancy(identified: ResultsDocument | Mapping[str, Any], track: DicTrack, rig: RigConfig,
                    flight_terms: tuple[FlightTerm, ...] = FLIGHT_TERMS,
                    cor_terms: tuple[str, ...] = CandidateLibrary.cor_terms, harmonics: bool = True) -> DiscrepancyRun:
    """The whole analysis of one recording (the module docstring): ``identified`` is the identification
    (a :class:`ResultsDocument`; a results.json mapping is read through the codec first).
    ``flight_terms``/``cor_terms``/``harmonics`` restrict the library (tests use this to check that an
    effect outside it is reported unexplained)."""
    library = CandidateLibrary(tuple(flight_terms), tuple(cor_terms), harmonics)
    return DiscrepancyEstimator(library).fit(measurement_of(identified, track, rig))


def analyse_discrepancy(identified: ResultsDocument | Mapping[str, Any], track: DicTrack, rig: RigConfig) -> dict:
    """The contract's ``discrepancy`` block (plus extras) for one recording; see the module docstring."""
    return run_discrepancy(identified, track, rig).document


def discrepancy_skip_reason(doc: ResultsDocument) -> str | None:
    """Why the discrepancy analysis does not apply to a results document, or None: no impacts (nothing for
    an impact model to be compared with), or a rig description inconsistent with the measurement."""
    blocking = [r for r in (doc.sections.get("rig_consistency") or []) if r.get("blocks_physics", True)]
    if blocking:
        keys = sorted({k for r in blocking for k in r.get("keys", [])})
        return ("discrepancy analysis skipped: the rig description is inconsistent with the measurement ("
                + ", ".join(keys) + "); no physics finding is built on it (see rig_consistency)")
    if not doc.impacts:
        motion = (doc.sections.get("motion") or {}).get("state")
        what = f" (recording: {motion.replace('_', ' ')})" if motion else ""
        return f"discrepancy analysis skipped: no impacts identified{what}, nothing to compare a model with"
    return None


def discrepancy_for_results(doc: ResultsDocument, track: DicTrack, rig: RigConfig
                            ) -> tuple[Discrepancy, DiscrepancyRun | None, str | None]:
    """For ``vibro analyze``: (discrepancy block, run or None, error message or None) from a results
    document. A recording the analysis cannot handle (too few flights, a model that fails) gives the
    baseline-only block with an ``error`` key instead of losing the identification. A recording without
    impacts, or whose rig description contradicts the measurement (``rig_consistency`` entries that block
    physics), is not analysed: the block carries ``skipped`` with the reason, returned as the message."""
    d0 = doc.simulation.deviation("cor_model")
    reason = discrepancy_skip_reason(doc)
    if reason is not None:
        return Discrepancy(d0, [], d0, {"skipped": reason}), None, reason
    try:
        run = run_discrepancy(doc, track, rig)
        return run.result, run, None
    except Exception as exc:  # noqa: BLE001 - reported, never fatal for the identification
        log.warning("discrepancy analysis failed: %s", exc)
        msg = f"discrepancy analysis failed: {type(exc).__name__}: {exc}"
        return Discrepancy(d0, [], d0, {"error": msg}), None, msg
