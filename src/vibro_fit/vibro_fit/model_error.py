"""The identification's COR sigmas with what its models leave in their residuals (issue 39).

Each impact's COR sigma (:func:`vibro_fit.impacts.paper_impact`) propagates the DIC noise through the two
parabolas and the structure sine. Where a parabola does not describe a flight (a force that depends on the
ball's position, a drag) or the sine not the structure near an impact, the residuals hold a smooth part whose
slope at the impact biases the velocities; :mod:`vibro_model.model_error` estimates it, pooled per plate and
side and counted only where significant, and :func:`model_error_pass` widens every impact's COR sigma by it.
Track units (mm) inside, m/s out. A model that fits keeps its sigmas.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_io.rig import RigConfig
from vibro_model.model_error import ImpactSlopes, ModelError, flight_residual_slope, local_sine_slope
from vibro_model.units import mm_to_m

from .flight_fit import FlightFit
from .impacts import ImpactFit
from .passes import HopPass


def _flight_slope(fl: FlightFit | None, track: DicTrack, t_s: float) -> tuple[float, float]:
    """(d, sd) in m/s: the slope at ``t_s`` of the smooth part of flight ``fl``'s parabola residuals."""
    if fl is None or fl.frames is None or len(fl.frames) == 0:
        return math.nan, math.nan
    frames = np.asarray(fl.frames, dtype=int)
    t = np.asarray(track.t_s, dtype=float)[frames]
    r = np.asarray(track.ball_mm, dtype=float)[frames] - np.asarray(fl.position_mm(t), dtype=float)
    d, sd = flight_residual_slope(t - fl.t_ref_s, r, t_s - fl.t_ref_s)
    return mm_to_m(d), mm_to_m(sd)


def _structure_slope(imp: ImpactFit, track: DicTrack, frequency_hz: float) -> tuple[float, float]:
    """(d, sd) in m/s: the slope at the impact of the impact's structure fit's residual within one drive period."""
    s = imp.structure
    if s is None or not math.isfinite(imp.t_s) or not frequency_hz > 0:
        return math.nan, math.nan
    t = np.asarray(track.t_s, dtype=float)
    sel = np.abs(t - imp.t_s) <= 1.0 / frequency_hz
    y = np.asarray(track.structure_mm, dtype=float)[sel]
    r = y - np.asarray(s.position_mm(t[sel]), dtype=float)
    d, sd = local_sine_slope(t[sel] - imp.t_s, r, 2.0 * math.pi * frequency_hz)
    return mm_to_m(d), mm_to_m(sd)


def impact_slopes(impacts: list[ImpactFit], flights: list[FlightFit], track: DicTrack,
                  frequency_hz: float) -> list[ImpactSlopes]:
    """The residual slopes at each impact with a COR (:class:`vibro_model.model_error.ImpactSlopes`)."""
    by_index = {int(f.index): f for f in flights}
    out = []
    for imp in impacts:
        if not math.isfinite(imp.cor):
            continue
        out.append(ImpactSlopes(plate=imp.plate,
                                before=_flight_slope(by_index.get(int(imp.flight_before)), track, imp.t_s),
                                after=_flight_slope(by_index.get(int(imp.flight_after)), track, imp.t_s),
                                structure=_structure_slope(imp, track, frequency_hz)))
    return out


def model_error_pass(impacts: list[ImpactFit], flights: list[FlightFit], track: DicTrack,
                     frequency_hz: float) -> tuple[list[ImpactFit], ModelError]:
    """``impacts`` with each COR sigma widened by the pooled model error of its plate (module docstring), and
    that model error (m/s)."""
    errors = ModelError.of(impact_slopes(impacts, flights, track, frequency_hz))
    out = []
    for imp in impacts:
        var = errors.cor_variance(imp.plate, imp.v_ball_before_mps, imp.v_ball_after_mps, imp.v_structure_mps) \
            if math.isfinite(imp.cor) and math.isfinite(imp.cor_std) else 0.0
        out.append(replace(imp, cor_std=math.sqrt(imp.cor_std ** 2 + var), cor_std_model=math.sqrt(var))
                   if var > 0 else imp)
    return out, errors


def widened_pass(hops: HopPass, track: DicTrack, rig: RigConfig) -> HopPass:
    """The identification's named pass: :func:`model_error_pass` on the hop pass' impacts and flights."""
    impacts, _ = model_error_pass(hops.impacts, hops.flights, track, float(rig.excitation.frequency_hz))
    return replace(hops, impacts=impacts)
