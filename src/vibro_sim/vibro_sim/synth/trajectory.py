"""Simulate the scenario with the COR model: lead-in, then the camera window."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dataclasses import replace

from ..cor_model import FlightRecord, ImpactEvent, SimResult, simulate_cor
from .invented import IndexShifted, stepped_cavity
from .scenario import Models, SynthConfig


@dataclass
class Trajectory:
    """Truth over the camera window; times are camera times (s), positions lab-frame (m)."""

    result: SimResult
    frame_t_s: np.ndarray
    ball_m: np.ndarray
    structure_m: np.ndarray
    impacts: list[ImpactEvent]
    flights: list[FlightRecord]

    @property
    def t_window(self) -> tuple[float, float]:
        return float(self.frame_t_s[0]), float(self.frame_t_s[-1])


def frame_times(cfg: SynthConfig) -> np.ndarray:
    """Camera time (s) of each frame: k / fps (rig t0_s = 0)."""
    return np.arange(cfg.frames) / cfg.fps


def simulate_window(cfg: SynthConfig, models: Models) -> Trajectory:
    """Run the COR model from ``-lead_in_s`` (ball at rest at the cavity centre) to the
    last frame plus one exposure; keep impacts and flights inside the frame window."""
    t_frames = frame_times(cfg)
    S = models.structure
    t_start = -cfg.lead_in_s
    t_end = float(t_frames[-1]) + cfg.exposure_s + 1.0 / cfg.fps
    if cfg.still:
        # Ball resting on the bottom plate, nothing moves.
        b = models.cavity.free_play_m
        ball = np.full(t_frames.shape, float(S.position(0.0)) - b)
        res = simulate_cor(S, models.cavity, models.restitution, models.force,
                           float(S.position(t_start)) - b, 0.0, t_start, t_end)
        return Trajectory(res, t_frames, ball, np.asarray(S.position(t_frames), dtype=float), [], [])
    if models.plate_step is not None and t_start < models.plate_step["step_time_s"] < t_end:
        res = _simulate_stepped(models, t_start, t_end)
    else:
        res = simulate_cor(S, models.cavity, models.restitution, models.force,
                           float(S.position(t_start)), 0.0, t_start, t_end)
    lo, hi = float(t_frames[0]), float(t_frames[-1])
    impacts = [i for i in res.impacts if lo <= i.t_s <= hi]
    flights = [f for f in res.flights if f.t_end_s > lo and f.t_start_s < hi]
    return Trajectory(res, t_frames, np.asarray(res.sample(t_frames), dtype=float),
                      np.asarray(S.position(t_frames), dtype=float), impacts, flights)


def _simulate_stepped(models: Models, t_start: float, t_end: float) -> SimResult:
    """The invented ``plate_step``: simulate to the step time, then on from the ball's state there with the
    stepped cavity (:func:`.invented.stepped_cavity`; it only grows, so the ball stays inside), and splice
    the two: one result on the unstepped structure (the lower plate, which DIC tracks), impacts and flights
    numbered on (the COR law sees the impact count go on), the flight across the step merged."""
    S = models.structure
    t_step = float(models.plate_step["step_time_s"])
    first = simulate_cor(S, models.cavity, models.restitution, models.force, float(S.position(t_start)), 0.0,
                         t_start, t_step)
    S2, cav2 = stepped_cavity(S, models.cavity, models.plate_step)
    n_imp, n_fl = len(first.impacts), len(first.flights)
    y, v = float(first.sample(t_step)), float(first.velocity(t_step))
    second = simulate_cor(S2, cav2, IndexShifted(models.restitution, n_imp), models.force, y, v, t_step, t_end)
    flights = list(first.flights)
    later = [replace(f, index=f.index + n_fl - 1) for f in second.flights]
    if flights and later and flights[-1].end_plate is None:
        a, b = flights.pop(), later.pop(0)
        later.insert(0, replace(b, index=a.index, t_start_s=a.t_start_s, start_plate=a.start_plate))
    else:
        later = [replace(f, index=f.index + 1) for f in later]
    out = SimResult(structure=S, cavity=models.cavity, t0_s=t_start, t_end_s=second.t_end_s,
                    impacts=list(first.impacts) + [replace(i, index=i.index + n_imp) for i in second.impacts],
                    flights=flights + later, stuck=list(first.stuck) + list(second.stuck),
                    segments=list(first.segments) + list(second.segments),
                    truncated=first.truncated or second.truncated)
    return out


def regime(traj: Trajectory, frequency_hz: float) -> dict:
    """Describe the impact regime in the window: impacts per cycle, strict top/bottom
    alternation, and the spread of the impact phase on each plate (rad)."""
    imps = traj.impacts
    lo, hi = traj.t_window
    cycles = (hi - lo) * frequency_hz
    plates = [i.plate for i in imps]
    alternating = all(a != b for a, b in zip(plates, plates[1:]))
    spread = {}
    for p in ("top", "bottom"):
        ph = np.array([(i.t_s * frequency_hz) % 1.0 for i in imps if i.plate == p]) * 2 * math.pi
        if ph.size:
            z = np.mean(np.exp(1j * ph))
            spread[p] = float(np.sqrt(max(0.0, -2 * np.log(max(abs(z), 1e-12)))))
        else:
            spread[p] = None  # no impact on this plate (JSON has no NaN)
    return {"impacts_per_cycle": len(imps) / cycles if cycles else 0.0,
            "alternating": alternating, "n_top": plates.count("top"),
            "n_bottom": plates.count("bottom"), "phase_spread_rad": spread,
            "stuck_phases": len([s for s in traj.result.stuck if s.t_end_s > lo and s.t_start_s < hi])}
