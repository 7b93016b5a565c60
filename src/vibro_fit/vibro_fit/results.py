"""Identification -> the results document (:mod:`vibro_model.results`) and CSV tables.

The types are SI inside; the contract's results.json (docs/recording-format.md: times s, positions mm,
velocities m/s, forces N) is written by :func:`vibro_io.results_file.write_results`. Flight coefficients
a, b, c are for Y = a t^2 + b t + c with t the absolute camera time (s). Only free flights carry a
friction force (null otherwise) and only impacts between two free flights are listed.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from vibro_io.outputs import atomic_open
from vibro_io.results_file import write_results
from vibro_model.codec import json_number, json_value
from vibro_model.results import ResultsDocument, Simulation

from .identify import Identification
from .statistics import normal_check

RESULTS_JSON = "results.json"
CSV_TABLES = ("flights.csv", "impacts.csv")  # written by write_csv_tables, in this order


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


def identification_extras(ident: Identification) -> dict[str, Any]:
    """The sections the model does not type yet: regime, identification details, accelerometers."""
    out: dict[str, Any] = {
        "regime": ident.regime.to_dict(),
        "contacts": [c.to_dict() for c in ident.contacts],
        "identification": {"method": ident.method, "weights": ident.weights, "noise_mm": ident.noise_mm,
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
                "n_matched": 0, "message": "clock offset not determined: no accelerometer impact near a DIC impact"},
            "impacts_not_seen_by_camera_s": None if ident.accel_unseen_s is None else list(ident.accel_unseen_s),
            "impacts": [{"t_daq": i.t_s, "plate": i.plate, "peak_mps2": i.peak_mps2,
                         "upper_energy_m2s3": i.energy_upper, "lower_energy_m2s3": i.energy_lower,
                         "dominant_frequencies_hz": list(i.dominant_frequencies_hz), "clipped": bool(i.clipped)}
                        for i in acc.impacts],
        }
        if getattr(ident, "coverage", None) is not None:
            out["accelerometers"]["coverage"] = ident.coverage.to_dict()
    return json_value(out)


def results_model(ident: Identification, recording: str, simulation: Simulation | None = None) -> ResultsDocument:
    """The results document of an identification (discrepancy left empty: the caller adds it)."""
    impacts = [i.model() for i in ident.impacts]
    sections = {"cor_statistics": cor_statistics_section(impacts), **identification_extras(ident)}
    return ResultsDocument.build(recording, ident.structure_motion(), [f.model(ident.mass_kg) for f in ident.flights],
                                 impacts, simulation=simulation, warnings=ident.warnings, sections=sections)


def results_document(ident: Identification, recording: str, simulation: dict | None = None,
                     discrepancy: dict | None = None) -> dict:
    """The whole results.json mapping (schema vibro.results/1) of an identification."""
    from vibro_model.results import Discrepancy

    doc = results_model(ident, recording, None if simulation is None else Simulation.from_dict(simulation))
    if discrepancy is not None:
        doc.discrepancy = Discrepancy.from_dict(discrepancy)
    return doc.to_dict()


def write_json(path: str | Path, doc: ResultsDocument | dict) -> Path:
    """results.json through the codec (validated)."""
    return write_results(path, doc)


def write_csv_tables(source: Identification | ResultsDocument, out_dir: str | Path) -> list[Path]:
    """flights.csv, impacts.csv (same columns as results.json) in ``out_dir``; returns the paths."""
    doc = source if isinstance(source, ResultsDocument) else results_model(source, "")
    out_dir = Path(out_dir)
    paths = []
    for name, rows in zip(CSV_TABLES, ([f.to_dict() for f in doc.flights], [i.to_dict() for i in doc.impacts])):
        path = out_dir / name
        with atomic_open(path, "w", newline="") as fh:
            if rows:
                names = list(dict.fromkeys(k for r in rows for k in r))   # optional keys of later rows too
                w = csv.DictWriter(fh, fieldnames=names)
                w.writeheader()
                w.writerows(rows)
            else:
                fh.write("index\n")
        paths.append(path)
    return paths
