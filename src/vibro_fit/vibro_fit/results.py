"""Identification -> the results.json sections of the contract (/shared/recording-format.md) and CSV tables.

Units: times s, positions mm, velocities m/s, forces N. Flight coefficients a, b, c are for
Y[mm] = a t^2 + b t + c with t the absolute camera time (s). Only free flights carry a friction force
(null otherwise) and only impacts between two free flights are listed.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .identify import Identification

SCHEMA = "vibro.results/1"


def _num(x: Any) -> Any:
    """JSON-safe number: numpy scalars to float, NaN/inf to None."""
    if x is None:
        return None
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    x = float(x)
    return x if math.isfinite(x) else None


def structure_section(ident: Identification) -> dict:
    """The fitted sine. A structure that does not move beyond DIC noise (``moving`` false) has no
    frequency or phase (null): a sine fitted to noise would claim one."""
    s = ident.structure
    sd = s.std
    moving = ident.motion.structure_moves if ident.motion is not None else True
    out = {"amplitude_mm": _num(s.amplitude_mm), "frequency_hz": _num(s.frequency_hz),
           "phase_rad": _num(s.phase_rad), "offset_mm": _num(s.offset_mm),
           "rms_residual_mm": _num(s.rms_residual_mm),
           "amplitude_std_mm": _num(sd[0]), "frequency_std_hz": _num(sd[1]), "phase_std_rad": _num(sd[2]),
           "offset_std_mm": _num(sd[3]), "n_points": s.n_points, "moving": bool(moving)}
    if not moving:
        out.update({"frequency_hz": None, "frequency_std_hz": None, "phase_rad": None, "phase_std_rad": None,
                    "note": "the structure does not move beyond DIC noise: no frequency or phase"})
    return out


def flights_section(ident: Identification) -> list[dict]:
    """One row per fitted flight. t_start / t_end are the impacts that open / close the flight when
    known, else its first / last fitted frame (``t_first_frame`` / ``t_last_frame`` always given)."""
    opens = {i.flight_after: i.t_s for i in ident.impacts}
    closes = {i.flight_before: i.t_s for i in ident.impacts}
    out = []
    for fl in ident.flights:
        a, b, c = fl.abs_coefficients()
        f_n, f_std = fl.friction_n(ident.mass_kg)
        out.append({"index": fl.index, "t_start": _num(opens.get(fl.index, fl.t_start_s)),
                    "t_end": _num(closes.get(fl.index, fl.t_end_s)),
                    "t_first_frame": _num(fl.t_start_s), "t_last_frame": _num(fl.t_end_s),
                    "a": _num(a), "b": _num(b), "c": _num(c), "direction": fl.direction or "up",
                    "friction_n": _num(f_n) if fl.is_free else None,
                    "friction_std_n": _num(f_std) if fl.is_free else None,
                    "rms_residual_mm": _num(fl.rms_residual_mm), "n_points": fl.n_points,
                    "free": bool(fl.is_free), "reason": fl.reason})
    return out


def impacts_section(ident: Identification) -> list[dict]:
    return [{"index": i.index, "t": _num(i.t_s), "t_std": _num(i.t_std_s), "plate": i.plate,
             "cor": _num(i.cor), "cor_std": _num(i.cor_std), "v_ball_before": _num(i.v_ball_before_ms),
             "v_ball_after": _num(i.v_ball_after_ms), "v_structure": _num(i.v_structure_ms),
             "flight_before": i.flight_before, "flight_after": i.flight_after, "method": i.method}
            for i in ident.impacts]


def cor_summary_section(ident: Identification) -> dict:
    return {p: {k: _num(v) for k, v in d.items()} for p, d in ident.cor_summary.items()}


def cor_statistics_section(ident: Identification) -> dict:
    """Per plate (n >= 3): histogram (counts, edges) and normal Q-Q slope, intercept and correlation r."""
    from .statistics import normal_check

    out = {}
    for plate in ("top", "bottom"):
        vals = [i.cor for i in ident.impacts if i.plate == plate]
        if len(vals) < 3:
            continue
        nc = normal_check(vals)
        out[plate] = {"histogram_counts": [int(c) for c in nc.counts], "histogram_edges": [_num(e) for e in nc.edges],
                      "qq_slope": _num(nc.slope), "qq_intercept": _num(nc.intercept), "qq_r": _num(nc.r)}
    return out


def identification_sections(ident: Identification) -> dict:
    """structure, flights, impacts, cor_summary (+ regime, plate geometry, accelerometers, warnings)."""
    out: dict[str, Any] = {
        "structure": structure_section(ident),
        "flights": flights_section(ident),
        "impacts": impacts_section(ident),
        "cor_summary": cor_summary_section(ident),
        "cor_statistics": cor_statistics_section(ident),
        "regime": ident.regime.to_dict(),
        "identification": {"method": ident.method, "weights": ident.weights, "noise_mm": _num(ident.noise_mm),
                           "plate_levels_mm": {k: _num(v) for k, v in ident.plate_levels.items()},
                           "short_flights": [{"t_start": _num(f.t_start_s), "t_end": _num(f.t_end_s),
                                              "n_points": f.n_points} for f in ident.short_flights],
                           "contact_phases": [{"t_start": _num(c.t_start_s), "t_end": _num(c.t_end_s),
                                               "n_frames": c.n} for c in ident.clusters if c.n > 4],
                           "impacts_without_cor": [{k: _num(v) if isinstance(v, float) else v
                                                    for k, v in ld.to_dict().items()} for ld in ident.landings]},
        "rig_consistency": [r.to_dict() for r in ident.rig_consistency],
        "warnings": list(ident.warnings),
    }
    if ident.motion is not None:
        out["motion"] = {k: _num(v) if isinstance(v, float) else v for k, v in ident.motion.to_dict().items()}
    if ident.accel is not None:
        acc = ident.accel
        out["accelerometers"] = {
            "n_impacts": len(acc.impacts), "threshold_ms2": _num(acc.threshold),
            "spectrum_peaks_hz": [_num(f) for f in acc.peaks_hz],
            "clipping": acc.clipping,
            "clock_offset_s": _num(ident.clock_offset.known_offset_s) if ident.clock_offset else None,
            "clock_offset_matched": ident.clock_offset.n_matched if ident.clock_offset else 0,
            "clock_offset_residual_std_s": _num(ident.clock_offset.residual_std_s) if ident.clock_offset else None,
            "clock_offset": ident.clock_offset.to_dict() if ident.clock_offset else {
                "determined": False, "offset_s": None, "reason": "no accelerometer impact near a DIC impact",
                "n_matched": 0, "message": "clock offset not determined: no accelerometer impact near a DIC impact"},
            "impacts_not_seen_by_camera_s": (None if ident.accel_unseen_s is None
                                             else [_num(x) for x in ident.accel_unseen_s]),
            "impacts": [{"t_daq": _num(i.t_s), "plate": i.plate, "peak_ms2": _num(i.peak_ms2),
                         "upper_energy_m2s3": _num(i.energy_upper), "lower_energy_m2s3": _num(i.energy_lower),
                         "dominant_frequencies_hz": [_num(f) for f in i.dominant_frequencies_hz],
                         "clipped": bool(i.clipped)} for i in acc.impacts],
        }
        if getattr(ident, "coverage", None) is not None:
            out["accelerometers"]["coverage"] = {k: (_num(v) if isinstance(v, float) else
                                                     [_num(x) for x in v] if isinstance(v, list) else v)
                                                 for k, v in ident.coverage.to_dict().items()}
    return out


def results_document(ident: Identification, recording: str, simulation: dict | None = None,
                     discrepancy: dict | None = None) -> dict:
    """The whole results.json mapping (schema vibro.results/1)."""
    doc = {"schema": SCHEMA, "recording": str(recording)}
    doc.update(identification_sections(ident))
    doc["simulation"] = simulation if simulation is not None else {
        "cor_model": {"deviation": None}, "hertz_model": {"deviation": None}}
    doc["discrepancy"] = discrepancy if discrepancy is not None else {
        "baseline_deviation": None, "findings": [], "final_deviation": None}
    return doc


def write_json(path: str | Path, doc: dict) -> None:
    Path(path).write_text(json.dumps(doc, indent=2, allow_nan=False), encoding="utf-8")


def write_csv_tables(ident: Identification, out_dir: str | Path) -> list[Path]:
    """flights.csv, impacts.csv (same columns as results.json) in ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    paths = []
    for name, rows in (("flights.csv", flights_section(ident)), ("impacts.csv", impacts_section(ident))):
        path = out_dir / name
        with path.open("w", newline="", encoding="utf-8") as fh:
            if rows:
                w = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
                w.writeheader()
                w.writerows(rows)
            else:
                fh.write("index\n")
        paths.append(path)
    return paths
