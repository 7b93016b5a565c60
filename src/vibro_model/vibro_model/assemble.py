"""The one assembler of the results document: stage outputs in, :class:`ResultsDocument` out.

Every path that writes results.json hands its stage outputs to :func:`assemble_results`: ``vibro analyze``
(:mod:`vibro_app.analyze`) and ``vibro fit`` from the cores they ran, ``vibro results`` and ``vibro replay``
(:mod:`vibro_app.bag_results`) from a bag's messages, the trajectory_fitter node's final pass from its
identification (what it publishes), the discrepancy node from the fitter's messages. The paths differ only in
where the stage outputs come from; the rules below are written here once:

- **sections** in one order: ``completeness``, ``cor_statistics``, the identification's own sections (regime,
  contacts, identification, rig_consistency, motion, accelerometers), ``dic_quality``, ``consistency``,
  ``impacts_model``, ``ball_spin``, ``provenance``;
- **warnings** in one order: the refusal first (``refused: ...``), then what the run lost (completeness), the
  identification's, the DIC's, the cross-checks', the simulation's, the discrepancy analysis', ``ball_spin``'s;
- **refusal** (a cross-check that withholds the results, :class:`ConsistencyStage`): no COR table (no impacts,
  an empty COR summary, no ``cor_statistics``), the friction withheld when it is the implausible part, rig.yaml
  statements that the refusal shows to be consequences dropped, ``complete`` false; nothing after the
  cross-checks (simulation, discrepancy, re-identification, ball spin) is added to a refused run;
- **completeness**: ``complete`` is false when the run lost anything (:class:`CompletenessStage`) or was refused;
- **re-identification** (:func:`apply_reidentification`): with a discrepancy stage, the impacts the final model
  measured again replace the identification's, which stay beside them (``cor_paper``, ``t_paper``), and the
  ``impacts_model`` section says which model each ``cor`` comes from; ``cor_summary`` and ``cor_statistics``
  are of the final CORs; a constant force along the axis that a finding names (an undeclared tilt) is taken
  out of every flight's Eq. 17 friction (:func:`apply_friction_correction`, the ``friction_model`` section).

Plain module (numpy only; no rclpy, no scipy at import): the fitter node and the CLI load it alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Sequence

import numpy as np

from vibro_model.codec import json_number, json_value
from vibro_model.results import (
    CorSummary,
    Discrepancy,
    Flight,
    Impact,
    ResultsDocument,
    Simulation,
    StructureMotion,
    link_impacts,
)
from vibro_model.statistics import normal_check

#: ``cor_method`` of an impact measured by the paper's identification (Eq. 15-16)
PAPER = "paper"
#: added to ``cor_method`` for an impact measured under the final model with a local structure velocity
LOCAL_STRUCTURE = "local_structure"
#: an identified impact and a re-measured one are the same when their times agree this well (s): both are
#: the same float read from the same results document
SAME_IMPACT_S = 1e-9


# ---------------------------------------------------------------- stage outputs
@dataclass(frozen=True, kw_only=True)
class Identified:
    """The identification stage as results types (SI): the structure, flights and impacts, its warnings and
    the sections only it fills (regime, contacts, identification, rig_consistency, motion, accelerometers)."""

    structure: StructureMotion | None
    flights: Sequence[Flight]
    impacts: Sequence[Impact]
    warnings: Sequence[str] = ()
    sections: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, kw_only=True)
class DicQualityStage:
    """The DIC's texture and correlation checks: the ``dic_quality`` section and its warning lines."""

    section: dict[str, Any]
    warnings: Sequence[str] = ()


@dataclass(frozen=True, kw_only=True)
class ConsistencyStage:
    """The cross-checks (:mod:`vibro_fit.cross_checks`): the ``consistency`` section (None when a recorded one
    could not be read: ``problem`` says why), one warning line per finding, and what a refusal withholds:
    ``refusal`` the refusal's line (None: not refused), ``withhold_friction`` whether the flights' friction is
    the implausible part, ``consequence_keys`` the rig.yaml keys whose statements the refusal shows to be its
    consequences (a statement about these keys only is dropped)."""

    section: dict[str, Any] | None
    warnings: Sequence[str] = ()
    refusal: str | None = None
    withhold_friction: bool = False
    consequence_keys: frozenset[str] = frozenset()
    problem: str = ""


@dataclass(frozen=True, kw_only=True)
class CompletenessStage:
    """What a graph run lost (frame slots without DIC, streams cut short, restarts): the ``completeness``
    section, its warning lines, and whether the run is whole."""

    section: dict[str, Any]
    warnings: Sequence[str] = ()
    complete: bool = True


@dataclass(frozen=True, kw_only=True)
class SimulationStage:
    """The COR and Hertz models replayed with the identified parameters: their runs and D, and the models that
    could not be replayed (one warning line each)."""

    simulation: Simulation
    warnings: Sequence[str] = ()


@dataclass(frozen=True, kw_only=True)
class LocalStructure:
    """An impact the final model measured again where its one structure fit does not follow the measured
    structure (a drive whose amplitude or phase moved during the take): its structure velocity there was off the
    local structure's by ``structure_velocity_misfit_mps``, so the impact is measured with the local structure
    velocity (the final model's flight law kept), which moved its COR by ``cor_shift`` from ``cor_global`` (the
    value under the global structure, not kept). Named by the identification's time ``t_paper_s``."""

    t_paper_s: float
    cor_global: float
    cor_shift: float
    structure_velocity_misfit_mps: float


@dataclass(frozen=True, kw_only=True)
class Reidentification:
    """Impacts measured again under the discrepancy analysis' final model: ``effects`` the findings that change
    how an impact is measured (empty: every impact keeps the identification's values), ``impacts`` the
    re-measured ones, each named by the identification's time (``t_paper_s``), and ``local_structure`` those
    of them measured with a local structure velocity (:class:`LocalStructure`)."""

    effects: Sequence[str] = ()
    impacts: Sequence[Impact] = ()
    local_structure: Sequence[LocalStructure] = ()
    friction: "FrictionCorrection | None" = None


@dataclass(frozen=True, kw_only=True)
class FrictionCorrection:
    """A constant force along the axis that the discrepancy analysis found and named (``effect``: an undeclared
    tilt, ``gravity_tilt``): Eq. 17 measures each flight's friction against the declared gravity g cos(theta),
    so every flight's ``friction_n`` holds it; the results subtract ``force_n`` (N, + up: m c, c the term's
    acceleration change) from each, with its sigma ``force_std_n`` added in quadrature, and say so (``words``,
    results.json ``friction_model``)."""

    effect: str
    force_n: float
    force_std_n: float
    words: str = ""


def apply_friction_correction(flights: Sequence[Flight], corr: FrictionCorrection | None
                              ) -> tuple[list[Flight], dict[str, Any] | None]:
    """The flights with each free flight's ``friction_n`` corrected by ``corr`` (``friction_paper_n`` the Eq. 17
    value, ``friction_method`` the effect) and the ``friction_model`` section; (flights, None) without one."""
    if corr is None:
        return list(flights), None
    out = [replace(f, friction_paper_n=f.friction_n, friction_method=corr.effect,
                   friction_n=f.friction_n - corr.force_n,
                   friction_std_n=None if f.friction_std_n is None else float(np.hypot(f.friction_std_n,
                                                                                       corr.force_std_n)))
           if f.friction_n is not None else f for f in flights]
    section = {"friction_method": corr.effect, "force_subtracted_n": json_number(corr.force_n),
               "force_subtracted_std_n": json_number(corr.force_std_n),
               "n_corrected": sum(f.friction_n is not None for f in flights), "description": corr.words}
    return out, section


@dataclass(frozen=True, kw_only=True)
class DiscrepancyStage:
    """The discrepancy analysis: its section, its warning lines (skipped, failed, not recorded), and the
    re-identification under its final model."""

    discrepancy: Discrepancy
    warnings: Sequence[str] = ()
    reidentification: Reidentification = field(default_factory=Reidentification)


@dataclass(frozen=True, kw_only=True)
class BallSpinStage:
    """The ball's spin per flight and impact: the ``ball_spin`` section, or None with ``why_not``."""

    section: dict[str, Any] | None
    why_not: str = ""


@dataclass(frozen=True, kw_only=True)
class StageOutputs:
    """Everything the stages of one run produced; a stage that did not run is None."""

    recording: str
    identified: Identified
    completeness: CompletenessStage | None = None
    dic_quality: DicQualityStage | None = None
    consistency: ConsistencyStage | None = None
    simulation: SimulationStage | None = None
    discrepancy: DiscrepancyStage | None = None
    ball_spin: BallSpinStage | None = None
    provenance: dict[str, Any] | None = None   # where the run came from (vibro analyze: command, inputs' SHA-256)


# ---------------------------------------------------------------- the assembler
def assemble_results(stages: StageOutputs) -> ResultsDocument:
    """The results document of a run's stage outputs, by the rules of the module docstring."""
    ident = stages.identified
    doc = ResultsDocument.build(stages.recording, ident.structure, ident.flights, ident.impacts)
    refusal = stages.consistency.refusal if stages.consistency is not None else None
    if refusal is None:
        doc = _with_later_stages(doc, stages)
    sections = _ordered_sections(stages, doc, refused=refusal is not None)
    warnings = _ordered_warnings(stages, refused=refusal is not None)
    complete = (stages.completeness is None or stages.completeness.complete) and refusal is None
    doc = replace(doc, sections=sections, warnings=warnings, complete=complete)
    if refusal is not None:
        doc = _withheld(doc, stages.consistency)
    return doc


def _with_later_stages(doc: ResultsDocument, stages: StageOutputs) -> ResultsDocument:
    """``doc`` with the simulation, the discrepancy analysis and the impacts re-measured under its final model
    (the stages after the cross-checks; a refused run has none)."""
    if stages.simulation is not None:
        doc = replace(doc, simulation=stages.simulation.simulation)
    if stages.discrepancy is not None:
        redo = stages.discrepancy.reidentification
        doc = apply_reidentification(replace(doc, discrepancy=stages.discrepancy.discrepancy), redo)
    return doc


def _ordered_sections(stages: StageOutputs, doc: ResultsDocument, refused: bool) -> dict[str, Any]:
    """The document's top-level sections in their one order (module docstring); ``cor_statistics`` of the
    document's final impacts, none for a refused run."""
    out: dict[str, Any] = {}
    if stages.completeness is not None:
        out["completeness"] = stages.completeness.section
    if not refused:  # a refused run's COR table is withheld, its statistics with it
        out["cor_statistics"] = cor_statistics_section(doc.impacts)
    out.update(stages.identified.sections)
    if stages.dic_quality is not None:
        out["dic_quality"] = stages.dic_quality.section
    if stages.consistency is not None and stages.consistency.section is not None:
        out["consistency"] = stages.consistency.section
    if "impacts_model" in doc.sections:
        out["impacts_model"] = doc.sections["impacts_model"]
    if "friction_model" in doc.sections:
        out["friction_model"] = doc.sections["friction_model"]
    if stages.ball_spin is not None and stages.ball_spin.section is not None and not refused:
        out["ball_spin"] = stages.ball_spin.section
    if stages.provenance is not None:
        out["provenance"] = stages.provenance
    return out


def _ordered_warnings(stages: StageOutputs, refused: bool) -> list[str]:
    """The document's warnings in their one order (module docstring)."""
    out: list[str] = []
    consistency = stages.consistency
    if refused:
        out.append(f"refused: {consistency.refusal}")
    if stages.completeness is not None:
        out += stages.completeness.warnings
    out += stages.identified.warnings
    if stages.dic_quality is not None:
        out += stages.dic_quality.warnings
    if consistency is not None:
        out += [consistency.problem] if consistency.problem else []
        out += consistency.warnings
    if refused:
        return out
    for stage in (stages.simulation, stages.discrepancy):
        out += stage.warnings if stage is not None else []
    if stages.discrepancy is not None and stages.discrepancy.reidentification.local_structure:
        out.append(_local_structure_warning(stages.discrepancy.reidentification.local_structure))
    if stages.ball_spin is not None and stages.ball_spin.section is None:
        out.append(f"ball_spin: not reported: {stages.ball_spin.why_not}")
    return out


def _withheld(doc: ResultsDocument, consistency: ConsistencyStage) -> ResultsDocument:
    """A refused run's document: the COR table withheld (no impacts, an empty COR summary and statistics), the
    friction withheld when it is implausible, and the rig.yaml statements about ``consequence_keys`` only
    dropped from ``rig_consistency`` and the warnings (the refusal has named the key that is wrong)."""
    sections = dict(doc.sections)
    flights = doc.flights
    if consistency.withhold_friction:
        flights = [replace(f, friction_n=None, friction_std_n=None) for f in flights]
    warnings = list(doc.warnings)
    statements = sections.get("rig_consistency")
    if consistency.consequence_keys and statements:
        dropped = [r for r in statements if set(r.get("keys", ())) <= consistency.consequence_keys]
        sections["rig_consistency"] = [r for r in statements if r not in dropped]
        texts = [r["message"] for r in dropped]
        warnings = [w for w in warnings if not w.startswith("measured free play") and not any(t in w for t in texts)]
    return replace(doc, flights=flights, impacts=[], cor_summary=CorSummary.of([]), sections=sections,
                   warnings=warnings)


# ---------------------------------------------------------------- rules used by the assembler
def cor_statistics_section(impacts: Iterable) -> dict:
    """Per plate (n >= 3): histogram (counts, edges) and normal Q-Q slope, intercept and correlation r of
    the CORs of ``impacts`` (anything with ``plate`` and ``cor``)."""
    impacts = list(impacts)
    out = {}
    for plate in ("top", "bottom"):
        vals = [np.nan if i.cor is None else i.cor for i in impacts if i.plate == plate]
        if len(vals) < 3:
            continue
        nc = normal_check(vals)
        out[plate] = {"histogram_counts": [int(c) for c in nc.counts], "histogram_edges": json_value(nc.edges),
                      "qq_slope": json_number(nc.slope), "qq_intercept": json_number(nc.intercept),
                      "qq_r": json_number(nc.r)}
    return out


def cor_method_name(effects: Sequence[str]) -> str:
    """The per-impact ``cor_method``: ``"paper"`` without an effect, else the effect names joined by '+'."""
    return "+".join(effects) if effects else PAPER


def _keep_paper(imp: Impact) -> Impact:
    return replace(imp, cor_paper=imp.cor, cor_std_paper=imp.cor_std, t_paper_s=imp.t_s, cor_method=PAPER)


def _impacts_model_section(effects: Sequence[str], n_done: int, n_cor: int) -> dict[str, Any]:
    """The ``impacts_model`` section: which model measured ``cor`` (``n_done`` of the ``n_cor`` impacts with a
    COR measured again under the final model of ``effects``)."""
    method = cor_method_name(effects)
    section = {"cor_method": method if n_done else PAPER, "effects": list(effects) if n_done else [],
               "n_reidentified": n_done, "n_paper": n_cor - n_done}
    if effects and n_done:
        section["description"] = (
            f"cor, cor_std, t, t_std, v_* of {n_done}/{n_cor} impacts measured under the final model "
            f"({', '.join(effects)}): impact time where its flights meet, structure velocity from its structure "
            "fit, ball velocities from its flights integrated with its force law; cor_paper, cor_std_paper, "
            "t_paper are the identification's (Eq. 15-16)"
            + (f"; {n_cor - n_done} impact(s) without a fitted flight on both sides keep them" if n_cor > n_done
               else ""))
    elif effects:
        section["description"] = (f"no impact was measured again under the final model ({', '.join(effects)}): "
                                  "cor is the identification's (Eq. 15-16)")
    else:
        section["description"] = ("no finding changes how an impact is measured: cor is the identification's "
                                  "(Eq. 15-16)")
    return section


def _by_time(entries: Iterable, name: str = "t_paper_s") -> dict[int, Any]:
    """Entries keyed by their identification time (in units of :data:`SAME_IMPACT_S`)."""
    return {round(getattr(e, name) / SAME_IMPACT_S): e for e in entries if getattr(e, name) is not None}


def _local_stretches(impacts: Sequence[Impact], local: dict[int, LocalStructure]) -> list[dict[str, Any]]:
    """Runs of consecutive impacts (time order; impacts without a COR do not break a run) measured with a local
    structure velocity: where, how many, and by how much the global structure would have been off."""
    stretches: list[list[tuple[Impact, LocalStructure]]] = []
    open_run = False
    for imp in impacts:
        entry = local.get(round(imp.t_s / SAME_IMPACT_S)) if imp.t_s is not None else None
        if entry is not None:
            if not open_run:
                stretches.append([])
            stretches[-1].append((imp, entry))
            open_run = True
        elif imp.cor is not None:
            open_run = False
    return [{"t_start_s": run[0][0].t_s, "t_end_s": run[-1][0].t_s, "n_impacts": len(run),
             "max_cor_shift": max(abs(k.cor_shift) for _, k in run),
             "max_structure_velocity_misfit_mps": max(abs(k.structure_velocity_misfit_mps) for _, k in run)}
            for run in stretches]


def _local_structure_warning(local: Sequence[LocalStructure]) -> str:
    """One line: how many impacts were measured with a local structure velocity, and why."""
    worst = max(local, key=lambda k: abs(k.cor_shift))
    return (f"impacts_model: {len(local)} impact(s) measured with the structure velocity of a fit local to each: "
            f"there the final model's one structure fit does not follow the measured structure (its velocity off "
            f"by up to {abs(worst.structure_velocity_misfit_mps) * 1e3:.3g} mm/s, which would move the COR by up "
            f"to {abs(worst.cor_shift):.2g}); the drive changed during the take? (impacts_model.local_structure)")


def apply_reidentification(doc: ResultsDocument, redo: Reidentification) -> ResultsDocument:
    """``doc`` with its impacts measured under the final model (``redo``): ``cor``, ``cor_std``, ``t``,
    ``t_std``, ``v_*`` replaced by the re-identified values, the identification's kept in ``cor_paper``,
    ``cor_std_paper``, ``t_paper``; ``cor_method`` per impact (``"paper"`` for an impact the final model did not
    measure; the effects and ``+local_structure`` for one measured with a local structure velocity,
    ``redo.local_structure``, listed by stretch in ``impacts_model``);
    ``cor_summary`` from the new CORs; the flights' opening/closing impact times from the new times; the
    top-level ``impacts_model`` section saying which model produced ``cor``. With no ``redo.effects`` every
    impact keeps the identification's values. The re-measured impacts name each impact by the identification's
    time, their ``t_paper_s``."""
    effects = redo.effects
    method = cor_method_name(effects)
    by_time = _by_time(redo.impacts) if effects else {}
    local = _by_time(redo.local_structure) if effects else {}
    impacts, n_done = [], 0
    for imp in doc.impacts:
        base = _keep_paper(imp)
        r = by_time.get(round(imp.t_s / SAME_IMPACT_S)) if imp.t_s is not None else None
        if r is None or imp.cor is None:
            impacts.append(base)
            continue
        n_done += 1
        how = method + ("+" + LOCAL_STRUCTURE if round(imp.t_s / SAME_IMPACT_S) in local else "")
        impacts.append(replace(base, t_s=r.t_s, t_std_s=r.t_std_s, cor=r.cor, cor_std=r.cor_std,
                               cor_std_model=r.cor_std_model,
                               v_ball_before_mps=r.v_ball_before_mps, v_ball_after_mps=r.v_ball_after_mps,
                               v_structure_mps=r.v_structure_mps, cor_method=how))
    n_cor = sum(i.cor is not None for i in doc.impacts)
    section = _impacts_model_section(effects, n_done, n_cor)
    if local:
        section["local_structure"] = _local_stretches(doc.impacts, local)
        section["description"] += (
            f"; {len(local)} impact(s) with the structure velocity of a fit local to each, where the final model's "
            "one structure fit does not follow the measured structure (local_structure; cor_method "
            f"'{method}+{LOCAL_STRUCTURE}')")
    sections = dict(doc.sections)
    sections["impacts_model"] = section
    flights, friction = apply_friction_correction(doc.flights, redo.friction)   # an undeclared tilt's force
    if friction is not None:
        sections["friction_model"] = friction
    # flights' t_start/t_end are the impacts that open/close them (the contract): the re-measured times
    return replace(doc, flights=link_impacts(flights, impacts), impacts=impacts,
                   cor_summary=CorSummary.of(impacts), sections=sections)
