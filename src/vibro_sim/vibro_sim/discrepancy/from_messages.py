"""Results sections and a DIC track from the fitter's and tracker's messages (for the ``discrepancy``
node), without rclpy: any objects with the fields of vibro_msgs StructureMotion, FreeFlight,
ImpactEstimate and DicFrame will do."""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from vibro_io.dictrack import DicTrack


def sections_from_messages(structure, flights: Iterable, impacts: Iterable) -> dict:
    """{"structure", "flights", "impacts"} as in results.json from final FreeFlight/ImpactEstimate
    messages (flight t_start/t_end are the opening/closing impacts when known, as vibro_fit.results)."""
    impacts = sorted(impacts, key=lambda m: m.index)
    flights = sorted(flights, key=lambda m: m.index)
    opens = {int(i.flight_after): float(i.t_s) for i in impacts}
    closes = {int(i.flight_before): float(i.t_s) for i in impacts}
    s = {"amplitude_mm": float(structure.amplitude_mm), "frequency_hz": float(structure.frequency_hz),
         "phase_rad": float(structure.phase_rad), "offset_mm": float(structure.offset_mm)}
    fl_rows = []
    for f in flights:
        k = int(f.index)
        fl_rows.append({"index": k, "t_start": opens.get(k, float(f.t_start_s)), "t_end": closes.get(k, float(f.t_end_s)),
                        "t_first_frame": float(f.t_start_s), "t_last_frame": float(f.t_end_s),
                        "a": float(f.a_mm_per_s2), "b": float(f.b_mm_per_s), "c": float(f.c_mm),
                        "direction": f.direction or "up", "friction_n": float(f.friction_n) if f.fitted else None,
                        "free": bool(f.fitted)})
    im_rows = [{"index": int(i.index), "t": float(i.t_s), "plate": i.plate, "cor": float(i.cor),
                "cor_std": float(i.cor_std), "v_ball_before": float(i.v_ball_before_m_per_s),
                "v_ball_after": float(i.v_ball_after_m_per_s), "v_structure": float(i.v_structure_m_per_s)}
               for i in impacts]
    return {"structure": s, "flights": fl_rows, "impacts": im_rows}


def track_from_messages(frames: Iterable) -> DicTrack:
    """A DicTrack from DicFrame messages (sorted by frame index; lost frames kept with NaN)."""
    rows = sorted(frames, key=lambda m: int(m.frame_index))

    def col(name, dtype=float):
        return np.array([getattr(m, name) for m in rows], dtype=dtype)

    lost = col("lost", bool)
    ball = col("ball_mm")
    struct = col("structure_mm")
    ball[lost] = math.nan
    struct[lost] = math.nan
    return DicTrack(frame=col("frame_index", int), t_s=col("t_s"), ball_mm=ball, structure_mm=struct,
                    ball_valid=col("ball_valid_points", int), structure_valid=col("structure_valid_points", int),
                    ball_zncc=col("ball_mean_zncc"), structure_zncc=col("structure_mean_zncc"), lost=lost)
