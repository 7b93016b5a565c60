"""The structure's velocity at each impact where the drive changed during the take.

Eq. 16 takes the structure's velocity at an impact from a sine fitted around it (the streaming fitter's window:
one period before the flight before the impact to the end of the flight after, about two periods, of constant
amplitude). Where the drive's amplitude or phase moves within that window (a shaker's amplitude stepping up over
0.1 s, a frequency drifting), the window's one sine misses the velocity at the impact: on a rendered take whose
amplitude rose 10 % over 0.1 s, by up to 3.6 mm/s, a COR error of 0.0095 (3.7 of its sigma) on an impact in the
ramp. The drive's verdict (:mod:`vibro_fit.drive`) says when this can happen.

:func:`local_velocity` fits the structure on half a period either side of the impact with amplitude, phase and
offset free to change linearly in time, y = (a + a1 tau) sin(w tau) + (b + b1 tau) cos(w tau) + c + c1 tau
(tau = t - t_impact, w from the take's fit), whose velocity at the impact is a w + b1 + c1: exact for a linear
ramp of amplitude or phase, and unbiased for a steady drive, where its noise (~0.012 mm/s median on rendered
recordings, against ~0.008 for the two-period sine) is far below a COR's. On that take its largest miss was
0.07 mm/s.

:func:`drive_velocity_pass` takes it into an impact's COR only where all of these hold:

- the drive is not stationary (a steady drive keeps the paper's Eq. 16 untouched);
- the two velocities differ by at least :data:`SHIFT_SIGMAS` of the local fit's sigma;
- the COR moves by at least :data:`COR_FLOOR_OF_SIGMA` of the noise part of its sigma.

Then the impact's ``v_structure`` is the local fit's, its COR recomputed (Eq. 16), and the local velocity's
variance added to ``cor_std`` (and to the paper fields of a paper COR, as :mod:`vibro_fit.plate_motion` does).
Units: times s, displacements mm, velocities m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vibro_model.model_error import LOCAL_HALF_WINDOW_PERIODS, cor_variance_of_biases, local_sine_slope
from vibro_model.units import mm_to_m

from .impacts import ImpactFit
from .plate_motion import cor_shift, noise_sigma

#: fewest good structure frames in the window (6 parameters)
MIN_POINTS = 16
#: the local velocity replaces the window sine's where they differ by this many of its sigmas
SHIFT_SIGMAS = 3.0
#: and where it moves the COR by this fraction of the noise part of the impact's COR sigma
COR_FLOOR_OF_SIGMA = 0.2


@dataclass(frozen=True)
class LocalVelocity:
    """The structure's velocity at an impact from the local fit (m/s), its 1-sigma (m/s), the frames it used."""

    v_mps: float
    sd_mps: float
    n_points: int


def local_velocity(t_s: np.ndarray, y_mm: np.ndarray, t_impact_s: float, frequency_hz: float
                   ) -> LocalVelocity | None:
    """The structure's velocity at ``t_impact_s`` from the fit on the samples (``t_s`` s, increasing, ``y_mm`` mm,
    good frames only) within :data:`~vibro_model.model_error.LOCAL_HALF_WINDOW_PERIODS` periods of it
    (:func:`vibro_model.model_error.local_sine_slope` with ``ramp``: the module docstring's model); None with fewer
    than :data:`MIN_POINTS` of them, or fewer than three on either side."""
    if not (frequency_hz > 0 and math.isfinite(t_impact_s)):
        return None
    half = LOCAL_HALF_WINDOW_PERIODS / frequency_hz
    lo = int(np.searchsorted(t_s, t_impact_s - half, side="left"))
    hi = int(np.searchsorted(t_s, t_impact_s + half, side="right"))
    tau = t_s[lo:hi] - t_impact_s
    if tau.size < MIN_POINTS or np.sum(tau < 0) < 3 or np.sum(tau > 0) < 3:
        return None
    v, sd = local_sine_slope(tau, y_mm[lo:hi], 2.0 * math.pi * frequency_hz, ramp=True)
    if not (math.isfinite(v) and math.isfinite(sd)):
        return None
    return LocalVelocity(v_mps=float(mm_to_m(v)), sd_mps=float(mm_to_m(sd)), n_points=int(tau.size))


def with_local_velocity(imp: ImpactFit, local: LocalVelocity) -> ImpactFit | None:
    """``imp`` with the structure velocity ``local`` (v_structure, COR by Eq. 16, the local velocity's variance
    added to cor_std and, for a paper COR, to the paper fields) where the pass's rules hold; None where they do
    not."""
    if imp.cor is None or imp.v_structure_mps is None or not math.isfinite(float(imp.v_structure_mps)):
        return None
    delta = local.v_mps - float(imp.v_structure_mps)
    if abs(delta) < SHIFT_SIGMAS * local.sd_mps:
        return None
    cor = cor_shift(imp, delta)
    if cor is None:
        return None
    noise = noise_sigma(imp)
    if math.isfinite(noise) and abs(cor - float(imp.cor)) < COR_FLOOR_OF_SIGMA * noise:
        return None
    vb, va = float(imp.v_ball_before_mps), float(imp.v_ball_after_mps)
    var = cor_variance_of_biases(vb, va, local.v_mps, 0.0, 0.0, local.sd_mps ** 2)
    sd = math.sqrt(float(imp.cor_std) ** 2 + var) if imp.cor_std is not None else None
    paper = imp.cor_method in (None, "paper")
    return replace(imp, cor=float(cor), cor_std=sd, v_structure_mps=local.v_mps,
                   cor_paper=float(cor) if paper and imp.cor_paper is not None else imp.cor_paper,
                   cor_std_paper=sd if paper and imp.cor_std_paper is not None else imp.cor_std_paper)


def drive_velocity_pass(impacts: list[ImpactFit], t_s: np.ndarray, y_mm: np.ndarray, frequency_hz: float,
                        stationary: bool | None) -> tuple[list[ImpactFit], list[str]]:
    """The identification's named pass: where the drive is not stationary (``stationary`` False), each impact's
    structure velocity from :func:`local_velocity` on the structure track (``t_s`` s, ``y_mm`` mm, good frames)
    taken into its COR by :func:`with_local_velocity`; the impacts, and a note saying how many moved and by how
    much. Anything else (a steady drive, one not tested): the impacts as they are, no note."""
    if stationary is not False:
        return impacts, []
    out, moved = [], []
    for imp in impacts:
        local = local_velocity(t_s, y_mm, float(imp.t_s), frequency_hz) if imp.t_s is not None else None
        new = with_local_velocity(imp, local) if local is not None else None
        if new is not None:
            moved.append(abs(float(new.cor) - float(imp.cor)))
        out.append(new if new is not None else imp)
    if not moved:
        return out, []
    note = (f"the drive is not stationary: the structure's velocity at {len(moved)} of {len(impacts)} impacts taken "
            f"from a fit of half a period either side of each (amplitude, phase and offset changing linearly), "
            f"which moved their CORs by up to {max(moved):.1e}")
    return out, [note]
