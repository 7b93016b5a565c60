"""What a recording shows, before anything is identified from it: still, structure moving with the ball
resting on it, or impacting.

Rules (positions mm, track coordinates):
- The structure *moves* when its fitted sine stands out of the DIC noise: the sine's RMS A/sqrt(2) is at
  least ``SNR_MIN`` (5) times the fit's residual RMS, and A is at least ``SNR_MIN`` times its own standard
  deviation. Otherwise no structure frequency, phase or amplitude is claimed (the fit then locks on noise:
  a 'frequency' of hundreds of Hz).
- The ball *moves relative to the structure* when the robust range (1st..99th percentile) of
  ball - structure exceeds ``SPREAD_MIN_SIGMA`` (20) times the ball's DIC noise sigma.
- ``impacting``: impacts (with or without a COR) were found. Otherwise ``still``: neither moves;
  ``structure_only``: the structure moves, the ball rests on it (does not move relative to it);
  ``ball_moving``: the ball moves relative to the structure but no impact was identified.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SNR_MIN = 5.0
SPREAD_MIN_SIGMA = 20.0

STATES = ("still", "structure_only", "ball_moving", "impacting")


@dataclass(frozen=True, kw_only=True)
class MotionState:
    """What moves in a recording (see module rules); amplitudes and noise in mm."""

    state: str
    structure_moves: bool
    structure_amplitude_mm: float
    structure_residual_mm: float
    ball_relative_range_mm: float
    ball_noise_mm: float
    n_impacts: int
    n_impacts_without_cor: int

    def message(self) -> str:
        s = (f"structure sine amplitude {self.structure_amplitude_mm:.5f} mm vs DIC residual "
             f"{self.structure_residual_mm:.5f} mm")
        b = (f"ball - structure range {self.ball_relative_range_mm:.4f} mm vs ball noise "
             f"{self.ball_noise_mm:.5f} mm")
        if self.state == "still":
            return f"still recording: neither the structure nor the ball moves beyond DIC noise ({s}; {b}); no impacts"
        if self.state == "structure_only":
            return f"structure moving, ball resting on it: no flight and no impact ({b})"
        if self.state == "ball_moving":
            return f"ball moving relative to the structure ({b}) but no impact identified"
        return (f"impacting: {self.n_impacts} impact(s) with a COR, {self.n_impacts_without_cor} without "
                "(see impacts_without_cor)")

    def to_dict(self) -> dict:
        return {"state": self.state, "structure_moves": self.structure_moves,
                "structure_amplitude_mm": float(self.structure_amplitude_mm),
                "structure_residual_mm": float(self.structure_residual_mm),
                "ball_relative_range_mm": float(self.ball_relative_range_mm),
                "ball_noise_mm": float(self.ball_noise_mm), "message": self.message()}


def structure_moves(amplitude_mm: float, amplitude_std_mm: float, residual_rms_mm: float) -> bool:
    """True when the structure's fitted sine stands out of the DIC noise (module rule)."""
    if not np.isfinite(amplitude_mm) or amplitude_mm <= 0:
        return False
    resid = max(float(residual_rms_mm), 1e-12)
    std = float(amplitude_std_mm) if np.isfinite(amplitude_std_mm) else np.inf
    return bool(amplitude_mm / np.sqrt(2.0) >= SNR_MIN * resid and amplitude_mm >= SNR_MIN * std)


def classify_motion(structure, y_rel_range_mm: float, ball_noise_mm: float, n_flights: int, n_impacts: int,
                    n_impacts_without_cor: int, structure_noise_mm: float | None = None) -> MotionState:
    """The recording's :class:`MotionState` from the structure fit, the ball's relative range and the counts
    of fitted flights and impacts; ``structure_noise_mm``: the structure track's noise (default: the fit's rms
    residual, which also holds a drive that moved over the take)."""
    noise = structure.rms_residual_mm if structure_noise_mm is None else structure_noise_mm
    moves = structure_moves(structure.amplitude_mm, float(structure.std[0]), noise)
    ball_moves = bool(y_rel_range_mm > SPREAD_MIN_SIGMA * max(ball_noise_mm, 1e-6))
    if n_impacts or n_impacts_without_cor:
        state = "impacting"
    elif not ball_moves:
        state = "structure_only" if moves else "still"
    else:
        state = "ball_moving"
    return MotionState(state=state, structure_moves=moves, structure_amplitude_mm=float(structure.amplitude_mm),
                       structure_residual_mm=float(structure.rms_residual_mm),
                       ball_relative_range_mm=float(y_rel_range_mm), ball_noise_mm=float(ball_noise_mm),
                       n_impacts=int(n_impacts), n_impacts_without_cor=int(n_impacts_without_cor))
