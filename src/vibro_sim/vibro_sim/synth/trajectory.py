"""Simulate the scenario with the COR model: lead-in, then the camera window."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..cor_model import FlightRecord, ImpactEvent, SimResult, simulate_cor
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
    res = simulate_cor(S, models.cavity, models.restitution, models.force,
                       float(S.position(t_start)), 0.0, t_start, t_end)
    lo, hi = float(t_frames[0]), float(t_frames[-1])
    impacts = [i for i in res.impacts if lo <= i.t_s <= hi]
    flights = [f for f in res.flights if f.t_end_s > lo and f.t_start_s < hi]
    return Trajectory(res, t_frames, np.asarray(res.sample(t_frames), dtype=float),
                      np.asarray(S.position(t_frames), dtype=float), impacts, flights)


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
