"""From identified quantities (as in results.json and the fitter's messages) to a model replay and D.

One path for ``vibro analyze`` and the ``simulator`` node. Conventions: positions in the
DIC frame (mm since frame 0, + up) as the fitter reports them; ``ball_offset_mm`` =
ball centre minus cavity centre at frame 0. The lab frame of the replay puts the cavity
centre on the fitted structure displacement, so the ball there is ``ball_dic + offset``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .deviation import deviation
from .params import BallCavity
from .replay import ReplayInputs, simulate_measured
from .structure import StructureMotion



@dataclass(frozen=True)
class StructureSine:
    """Y_s(t) = amplitude_mm sin(2 pi frequency_hz t + phase_rad) + offset_mm, t camera time (s)."""

    amplitude_mm: float
    frequency_hz: float
    phase_rad: float
    offset_mm: float

    def motion(self) -> StructureMotion:
        return StructureMotion(self.amplitude_mm * 1e-3, self.frequency_hz, self.phase_rad, self.offset_mm * 1e-3)


@dataclass(frozen=True)
class FlightSummary:
    """One fitted flight: Y_b = a t^2 + b t + c (mm, t in s), friction (N, + up), free or not."""

    t_start_s: float
    t_end_s: float
    a: float
    b: float
    c: float
    friction_n: float
    free: bool = True

    def position_mm(self, t_s):
        return (self.a * t_s + self.b) * t_s + self.c

    def velocity_ms(self, t_s):
        return (2.0 * self.a * t_s + self.b) * 1e-3


@dataclass(frozen=True)
class ImpactSummary:
    t_s: float
    plate: str
    cor: float


def replay_inputs(structure: StructureSine, flights: Sequence[FlightSummary], impacts: Sequence[ImpactSummary],
                  ball_offset_mm: float, free_play_mm: float, t_end_s: float) -> ReplayInputs:
    """Start at the first free flight with its fitted state; CORs and forces as identified."""
    free = [f for f in flights if f.free]
    if not free:
        raise ValueError("no free flight: nothing to replay")
    if not impacts:
        raise ValueError("no impact: nothing to replay")
    first = free[0]
    t0 = first.t_start_s
    motion = structure.motion()
    y_rel_mm = float(first.position_mm(t0)) + ball_offset_mm - 1e3 * float(motion.position(t0))
    b = free_play_mm
    y_rel_mm = float(np.clip(y_rel_mm, -0.999 * b, 0.999 * b))
    v_rel = float(first.velocity_ms(t0)) - float(motion.velocity(t0))
    later = [i for i in impacts if i.t_s > t0]
    forces = [f.friction_n if f.free else 0.0 for f in flights if f.t_end_s > t0]
    return ReplayInputs(structure=motion, impact_times_s=[i.t_s for i in later],
                        impact_plates=[i.plate for i in later], impact_cors=[i.cor for i in later],
                        flight_forces_n=forces, t_start_s=t0, y_rel_m=1e-3 * y_rel_mm, v_rel_ms=v_rel,
                        t_end_s=float(t_end_s))


def replay_and_score(inputs: ReplayInputs, cavity: BallCavity, t_s: np.ndarray, ball_dic_mm: np.ndarray,
                     ball_offset_mm: float, models: Sequence[str] = ("cor_model", "hertz_model"),
                     ) -> dict[str, dict]:
    """Simulate each model and score it against the measured ball (DIC frame, mm) by D (Eq. 18).

    Only samples within [t_start_s, t_end_s] with finite measurements count. Returns
    ``{model: {"deviation": D, "t_s": times, "ball_mm": simulated (DIC frame), "measured_mm": ...,
    "impacts": simulated impact count}}``; a model that fails gives ``{"error": message}``.
    """
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(ball_dic_mm, dtype=float)
    keep = np.isfinite(y) & (t >= inputs.t_start_s) & (t <= inputs.t_end_s)
    t, y = t[keep], y[keep]
    out: dict[str, dict] = {}
    for name in models:
        try:
            sim_m, result = simulate_measured(inputs, cavity, t, models=(name,))[name]
        except Exception as exc:  # a model failing must not lose the identification
            out[name] = {"error": f"{type(exc).__name__}: {exc}"}
            continue
        sim_mm = 1e3 * sim_m - ball_offset_mm
        out[name] = {"deviation": float(deviation(t, sim_mm, y)), "t_s": t, "ball_mm": sim_mm,
                     "measured_mm": y, "impacts": len(result.impacts)}
    return out
