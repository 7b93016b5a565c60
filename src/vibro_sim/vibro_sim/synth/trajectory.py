"""Simulate the scenario with the COR model: lead-in, then the camera window."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vibro_model.results import Impact

from ..cor_model import FlightRecord, SimResult, simulate_cor
from .invented import IndexShifted, creeping_plate, stepped_cavity
from .scenario import HORIZONTAL_FROM_DEG, Models, SynthConfig


@dataclass
class Trajectory:
    """Truth over the camera window; times are camera times (s), positions lab-frame (m)."""

    result: SimResult
    frame_t_s: np.ndarray
    ball_m: np.ndarray
    structure_m: np.ndarray
    impacts: list[Impact]
    flights: list[FlightRecord]

    @property
    def t_window(self) -> tuple[float, float]:
        return float(self.frame_t_s[0]), float(self.frame_t_s[-1])


def frame_times(cfg: SynthConfig) -> np.ndarray:
    """Camera time (s) of each frame: k / fps (rig t0_s = 0)."""
    return np.arange(cfg.frames) / cfg.fps


def start_speed_mps(models: Models) -> float:
    """The ball's speed at the start of the lead-in (m/s, up): 0 (at rest at the cavity centre, gravity brings it
    to the lower plate) unless the axis is within 90 - :data:`HORIZONTAL_FROM_DEG` deg of horizontal (gravity along
    it below 0.2 g); then 4 b f, the speed that crosses the cavity (2 b) in half a drive period: at rest in
    mid-cavity with no gravity along the axis the ball would never reach a plate."""
    cav = models.cavity
    if abs(cav.g_eff_mps2) >= cav.gravity_mps2 * math.cos(math.radians(HORIZONTAL_FROM_DEG)):
        return 0.0
    return 4.0 * cav.free_play_m * models.structure.frequency_hz


def simulate_window(cfg: SynthConfig, models: Models) -> Trajectory:
    """Run the COR model from ``-lead_in_s`` (ball at the cavity centre, at rest or with
    :func:`start_speed_mps` on a horizontal axis) to the last frame plus one exposure; keep impacts and flights
    inside the frame window."""
    t_frames = frame_times(cfg)
    S = models.structure
    t_start = -cfg.lead_in_s
    t_end = float(t_frames[-1]) + cfg.exposure_s + 1.0 / cfg.fps
    if cfg.still:
        # Ball resting on the bottom plate, nothing moves.
        b = models.cavity.free_play_m
        ball = np.full(t_frames.shape, float(S.position(0.0)) - b)
        res = simulate_cor(S, models.cavity, models.restitution, models.force,
                           y0_m=float(S.position(t_start)) - b, v0_mps=0.0, t0_s=t_start, t_end_s=t_end)
        return Trajectory(res, t_frames, ball, np.asarray(S.position(t_frames), dtype=float), [], [])
    splits = []
    if models.cor_drift_per_impact:
        splits.append(float(t_frames[0]))
    if models.plate_step is not None:
        splits.append(float(models.plate_step["step_time_s"]))
    splits = sorted(x for x in set(splits) if t_start < x < t_end)
    if splits:
        res = _simulate_pieces(models, [t_start] + splits + [t_end], float(t_frames[0]))
    else:
        res = simulate_cor(S, models.cavity, models.restitution, models.force,
                           y0_m=float(S.position(t_start)), v0_mps=start_speed_mps(models), t0_s=t_start,
                           t_end_s=t_end, plates=moved_plates(models, S))
    lo, hi = float(t_frames[0]), float(t_frames[-1])
    impacts = [i for i in res.impacts if lo <= i.t_s <= hi]
    flights = [f for f in res.flights if f.t_end_s > lo and f.t_start_s < hi]
    return Trajectory(res, t_frames, np.asarray(res.sample(t_frames), dtype=float),
                      np.asarray(S.position(t_frames), dtype=float), impacts, flights)


def _simulate_pieces(models: Models, bounds: list[float], t_window_s: float) -> SimResult:
    """The invented effects that change the physics at a time: simulate piece by piece between ``bounds``,
    each piece from the ball's state at the end of the one before, and splice them into one result on
    the unstepped structure (the lower plate, which DIC tracks): impacts and flights numbered on (the COR
    law sees the impact count go on), a flight across a boundary merged. From ``plate_step``'s time on the
    cavity is the stepped one (:func:`.invented.stepped_cavity`; it only grows, so the ball stays inside);
    from frame 0 (``t_window_s``) on the COR law is the window's (``cor_drift``: :meth:`Models.window_laws`)."""
    S = models.structure
    step_t = float(models.plate_step["step_time_s"]) if models.plate_step is not None else math.inf
    pieces: list[SimResult] = []
    y, v = float(S.position(bounds[0])), start_speed_mps(models)
    n_imp = 0
    law = models.restitution
    for a, b in zip(bounds[:-1], bounds[1:]):
        S_k, cav_k = (stepped_cavity(S, models.cavity, models.plate_step) if a >= step_t
                      else (S, models.cavity))
        if a >= t_window_s and models.cor_drift_per_impact and law is models.restitution:
            law = models.window_laws(n_imp)[0]
        res = simulate_cor(S_k, cav_k, IndexShifted(law, n_imp), models.force, y0_m=y, v0_mps=v, t0_s=a, t_end_s=b,
                           plates=moved_plates(models, S_k))
        res.impacts = [replace(i, index=i.index + n_imp) for i in res.impacts]
        n_imp += len(res.impacts)
        y, v = float(res.sample(b)), float(res.velocity(b))
        pieces.append(res)
    impacts, flights, stuck, segments = [], [], [], []
    for res in pieces:
        later = [replace(f, index=f.index + len(flights)) for f in res.flights]
        if flights and later and flights[-1].end_plate is None and later[0].start_plate is None:
            a_, b_ = flights.pop(), later.pop(0)
            later = [replace(b_, index=a_.index, t_start_s=a_.t_start_s, start_plate=a_.start_plate)] + \
                [replace(f, index=f.index - 1) for f in later]
        impacts += res.impacts
        flights += later
        stuck += res.stuck
        segments += res.segments
    return SimResult(structure=S, cavity=models.cavity, t0_s=bounds[0], t_end_s=pieces[-1].t_end_s, impacts=impacts,
                     flights=flights, stuck=stuck, segments=segments, truncated=any(r.truncated for r in pieces))


def moved_plates(models: Models, S) -> dict:
    """The plates that move against structure ``S`` (``plate_creep``: the upper one), with their kinematics."""
    return {"top": creeping_plate(S, models.plate_creep)} if models.plate_creep is not None else {}


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
