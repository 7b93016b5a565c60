"""From the identified motion (the domain model, :mod:`vibro_model.results`) to a model replay and D.

One path for ``vibro analyze`` and the ``simulator`` node, SI throughout (m, m/s, s, N). Conventions:
positions in the DIC frame (displacement since frame 0, + up) as the fitter reports them;
``ball_offset_m`` = ball centre minus cavity centre at frame 0 (``StructureMotion.ball_offset_m``). The
lab frame of the replay puts the cavity centre on the fitted structure displacement, so the ball there is
``ball_dic + offset``. A flight starts and ends at its first/last fitted frame here (the fitter's
FreeFlight carries those), not at the impacts that open/close it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from vibro_model.codec import nan_if_none
from vibro_model.drive_envelope import DriveEnvelope, under_envelope
from vibro_model.results import Flight, Impact, SimulationRun, StructureMotion

from .deviation import deviation
from .params import BallCavity
from .replay import ReplayInputs, simulate_measured


def _flight_state(flight: Flight, t_s: float) -> tuple[float, float]:
    """Position (m) and velocity (m/s) of the identified parabola Y_b = a t^2 + b t + c at ``t_s``."""
    a, b, c = (nan_if_none(v) for v in (flight.a_mps2, flight.b_mps, flight.c_m))
    return (a * t_s + b) * t_s + c, 2.0 * a * t_s + b


def replay_inputs(structure: StructureMotion, flights: Sequence[Flight], impacts: Sequence[Impact],
                  free_play_m: float, t_end_s: float, ball_offset_m: float | None = None,
                  envelope: DriveEnvelope | None = None) -> ReplayInputs:
    """Start at the first free flight's first fitted frame with its fitted state; CORs and forces as
    identified (a flight that is not free: no force). ``ball_offset_m`` defaults to the structure's.
    ``envelope``: the drive as it moved over the take (:mod:`vibro_model.drive_envelope`, from the windowed
    drive where it was found not stationary); the structure then follows it instead of the take's average sine."""
    free = [f for f in flights if f.free]
    if not free:
        raise ValueError("no free flight: nothing to replay")
    if not impacts:
        raise ValueError("no impact: nothing to replay")
    offset_m = structure.ball_offset_m if ball_offset_m is None else ball_offset_m
    t0 = nan_if_none(free[0].t_first_frame_s)
    motion = under_envelope(structure.kinematics(), envelope)
    y_m, v_mps = _flight_state(free[0], t0)
    y_rel_m = float(np.clip(y_m + nan_if_none(offset_m) - float(motion.position(t0)),
                            -0.999 * free_play_m, 0.999 * free_play_m))
    later = [i for i in impacts if i.t_s is not None and i.t_s > t0]
    forces = [nan_if_none(f.friction_n) if f.free else 0.0 for f in flights
              if f.t_last_frame_s is not None and f.t_last_frame_s > t0]
    return ReplayInputs(structure=motion, impact_times_s=[i.t_s for i in later],
                        impact_plates=[i.plate for i in later], impact_cors=[nan_if_none(i.cor) for i in later],
                        flight_forces_n=forces, t_start_s=t0, y_rel_m=y_rel_m,
                        v_rel_mps=v_mps - float(motion.velocity(t0)), t_end_s=float(t_end_s))


def replay_and_score(inputs: ReplayInputs, cavity: BallCavity, t_s: np.ndarray, ball_dic_m: np.ndarray,
                     ball_offset_m: float, models: Sequence[str] = ("cor_model", "hertz_model"),
                     ) -> tuple[dict[str, SimulationRun], dict[str, str]]:
    """Simulate each model and score it against the measured ball (DIC frame, m) by D (Eq. 18).

    Only samples within [t_start_s, t_end_s] with finite measurements count. Returns (runs, errors):
    ``runs[model]`` a :class:`SimulationRun` (D, simulated impact count, the compared times, simulated and
    measured ball in the DIC frame), ``errors[model]`` the message of a model that failed.
    """
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(ball_dic_m, dtype=float)
    keep = np.isfinite(y) & (t >= inputs.t_start_s) & (t <= inputs.t_end_s)
    t, y = t[keep], y[keep]
    runs: dict[str, SimulationRun] = {}
    errors: dict[str, str] = {}
    for name in models:
        try:
            sim_m, result = simulate_measured(inputs, cavity, t, models=(name,))[name]
        except Exception as exc:  # a model failing must not lose the identification
            errors[name] = f"{type(exc).__name__}: {exc}"
            continue
        sim_dic_m = np.asarray(sim_m, dtype=float) - ball_offset_m
        runs[name] = SimulationRun(name, float(deviation(t, sim_dic_m, y)), len(result.impacts), t, sim_dic_m, y)
    return runs, errors


def decimated(run: SimulationRun, max_points: int) -> SimulationRun:
    """``run`` with at most ``max_points`` samples (every k-th)."""
    step = max(1, int(np.ceil(run.t_s.size / max_points)))
    return replace(run, t_s=run.t_s[::step], ball_m=run.ball_m[::step], measured_ball_m=run.measured_ball_m[::step])
