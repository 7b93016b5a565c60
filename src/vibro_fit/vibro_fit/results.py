"""Identification -> the results document (:mod:`vibro_model.results`) and CSV tables.

The types are SI inside; the contract's results.json (docs/recording-format.md: times s, positions mm,
velocities m/s, forces N) is written by :func:`vibro_io.results_file.write_results`. Flight coefficients
a, b, c are for Y = a t^2 + b t + c with t the absolute camera time (s). Only free flights carry a
friction force (null otherwise) and only impacts between two free flights are listed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vibro_io.results_file import CSV_TABLES, RESULTS_JSON, write_result_tables, write_results
from vibro_model.assemble import Identified, StageOutputs, assemble_results
from vibro_model.codec import json_value
from vibro_model.results import ResultsDocument, Simulation

from .identify import Identification

__all__ = ["CSV_TABLES", "RESULTS_JSON", "identification_extras", "identified_stage", "results_document",
           "results_model", "write_csv_tables", "write_json"]


def identification_extras(ident: Identification) -> dict[str, Any]:
    """The sections the model does not type yet: regime, identification details, accelerometers."""
    out: dict[str, Any] = {
        "regime": ident.regime.to_dict(),
        "contacts": [c.to_dict() for c in ident.contacts],
        "identification": {"method": ident.method, "weights": ident.weights, "noise_mm": ident.noise_mm,
                           "axis_gravity_mps2": ident.g_axis_mps2,   # g cos(setup.axis_tilt_deg): Eq. 17's g
                           "plate_levels_mm": dict(ident.plate_levels),
                           "short_flights": [{"t_start": f.t_start_s, "t_end": f.t_end_s, "n_points": f.n_points}
                                             for f in ident.short_flights],
                           "contact_phases": [{"t_start": c.t_start_s, "t_end": c.t_end_s, "n_frames": c.n}
                                              for c in ident.clusters if c.n > 4],
                           "impacts_without_cor": [ld.to_dict() for ld in ident.landings],
                           "gaps": [g.to_dict() for g in ident.gaps]},
        "rig_consistency": [r.to_dict() for r in ident.rig_consistency],
    }
    if ident.motion is not None:
        out["motion"] = ident.motion.to_dict()
    if getattr(ident, "drive", None) is not None:   # the windowed drive, stationary or not (vibro_fit.drive)
        out["drive"] = ident.drive.to_dict()
    if getattr(ident, "dic_bias", None) is not None:   # DIC's sub-pixel bias, measured (vibro_fit.subpixel_bias)
        out["dic_bias"] = ident.dic_bias.to_dict()
    if getattr(ident, "plate_motion", None):   # each plate against the tracked structure (vibro_fit.plate_motion)
        out["plate_motion"] = {plate: m.to_dict() for plate, m in ident.plate_motion.items()}
    if ident.accel is not None:
        acc, off = ident.accel, ident.clock_offset
        out["accelerometers"] = {
            "n_impacts": len(acc.impacts), "threshold_mps2": acc.threshold, "spectrum_peaks_hz": list(acc.peaks_hz),
            "clipping": acc.clipping,
            "clock_offset_s": off.known_offset_s if off else None,
            "clock_offset_matched": off.n_matched if off else 0,
            "clock_offset_residual_std_s": off.residual_std_s if off else None,
            "clock_offset": off.to_dict() if off else {
                "determined": False, "offset_s": None, "reason": "no accelerometer impact near a DIC impact",
                "n_matched": 0, "message": "clock offset not determined: no accelerometer impact near a DIC impact",
                "rate_ppm": None, "rate_std_ppm": None, "offset_std_s": None, "t_ref_s": None},
            "impacts_not_seen_by_camera_s": None if ident.accel_unseen_s is None else list(ident.accel_unseen_s),
            "impacts": [{"t_daq": i.t_s, "t_camera": t_cam, "plate": i.plate, "peak_mps2": i.peak_mps2,
                         "upper_energy_m2s3": i.energy_upper, "lower_energy_m2s3": i.energy_lower,
                         "dominant_frequencies_hz": list(i.dominant_frequencies_hz), "clipped": bool(i.clipped)}
                        for i, t_cam in zip(acc.impacts, _accel_camera_times(acc, off))],
        }
        if getattr(ident, "coverage", None) is not None:
            out["accelerometers"]["coverage"] = ident.coverage.to_dict()
    return json_value(out)


def _accel_camera_times(acc, off) -> list[float | None]:
    """Each accelerometer impact's time on the camera clock (s; offset and rate of ``off``), None for every one
    while the clock offset is not determined."""
    if off is None or not off.determined or not acc.impacts:
        return [None] * len(acc.impacts)
    return off.camera_s([i.t_s for i in acc.impacts])


def identified_stage(ident: Identification) -> Identified:
    """The identification as the results assembler takes it (:class:`vibro_model.assemble.Identified`): the
    structure, flights and impacts as results types, its warnings, and the sections only it fills."""
    flights = [f.model(ident.mass_kg, ident.g_axis_mps2) for f in ident.flights]
    return Identified(structure=ident.structure_motion(), flights=flights,
                      impacts=[i.model() for i in ident.impacts], warnings=list(ident.warnings),
                      sections=identification_extras(ident))


def results_model(ident: Identification, recording: str) -> ResultsDocument:
    """The results document of an identification alone (``vibro fit``; no later stage): the assembler's
    (:func:`vibro_model.assemble.assemble_results`)."""
    return assemble_results(StageOutputs(recording=recording, identified=identified_stage(ident)))


def results_document(ident: Identification, recording: str, simulation: dict | None = None,
                     discrepancy: dict | None = None) -> dict:
    """The whole results.json mapping (schema vibro.results/1) of an identification, with a simulation and
    discrepancy section given as results.json mappings (tests, the prove harness)."""
    from vibro_model.results import Discrepancy

    doc = results_model(ident, recording)
    if simulation is not None:
        doc.simulation = Simulation.from_dict(simulation)
    if discrepancy is not None:
        doc.discrepancy = Discrepancy.from_dict(discrepancy)
    return doc.to_dict()


def write_json(path: str | Path, doc: ResultsDocument | dict) -> Path:
    """results.json through the codec (validated)."""
    return write_results(path, doc)


def write_csv_tables(source: Identification | ResultsDocument, out_dir: str | Path) -> list[Path]:
    """flights.csv, impacts.csv of an identification or a results document in ``out_dir``
    (:func:`vibro_io.results_file.write_result_tables`); returns the paths."""
    doc = source if isinstance(source, ResultsDocument) else results_model(source, "")
    return write_result_tables(doc, out_dir)
