"""DIC's sub-pixel bias (the S-curve), measured on the recording itself and taken out of the track (issue 39).

A sub-pixel estimator (ZNCC with interpolation, as Eq. 1 is solved) is biased by a periodic function of the
displacement's fractional pixel, the "S-curve": on this project's rendered recordings about 0.004 px (0.2 um at
0.06 mm/px) for both bodies, most of the DIC error (82 % of the structure's error variance). It is not white
noise: the structure sweeps the same pixels every cycle and the ball repeats its flights, so the bias repeats
with the drive and moves the structure's fitted harmonics and the flights' fitted states the same way at every
impact. The COR sigmas, which hold white noise, then held 35-52 % of the errors on recordings whose model is
right (a third harmonic, drag with harmonics), with every impact's error of one sign.

The bias is a function of the displacement d (px) = track mm / camera.mm_per_px (the subsets start at integer
pixels in frame 0, so d's fraction is the interpolation's offset): b(d) = sum_m a_m sin(2 pi m d) + b_m cos(2 pi
m d), m = 1..:data:`ORDERS`. It is fitted jointly with a motion model that holds whatever the bodies do at the
drive's time scales, so that no physics leaks into it (the structure sweeps tens of pixels per cycle, so b(d)
varies many times faster than any harmonic the model holds):

- **structure**: in windows of :data:`STRUCTURE_WINDOW_S`, an offset, a drift and the drive's harmonics 1..
  :data:`STRUCTURE_HARMONICS` with the fundamental's amplitude and phase changing linearly (a drive that ramps);
- **ball**: every free flight its own cubic (gravity, drag, a force the parabola leaves out).

Each block is projected out (Frisch-Waugh), so a 20,000-frame take solves a 4-column least squares. The bias
is taken out of that body's track (:mod:`vibro_io.dic_bias`, results.json's ``dic_bias`` section) only where it
is told from noise and matters (:func:`decide`): its amplitude above :data:`MIN_Z` standard errors and
:data:`FLOOR_PX`, the body sweeping at least :data:`MIN_SWEEP_PX` (else b(d) cannot be told from the motion),
and the fit's residual lower with it. Otherwise nothing changes and the reason is said. The identification then
runs again on the corrected track (:func:`vibro_fit.identify.identify`).

Plain numpy; track units (mm, s) inside, px in what is reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Iterable, Sequence

import numpy as np

from vibro_io.dic_bias import BodyBias, SubpixelBias, bias_columns
from vibro_io.dictrack import DicTrack

#: S-curve harmonics in the fractional pixel (m = 1, 2: the measured second is 7 % of the first)
ORDERS = 2
#: the structure's motion model: windows of this length (s), each with its own drive harmonics
STRUCTURE_WINDOW_S = 0.5
#: drive harmonics held in each structure window (a 3rd or 5th harmonic of a few % must not leak into b(d))
STRUCTURE_HARMONICS = 8
#: a bias is taken out beyond this many of its standard errors (several bodies and orders are tested: strict)
MIN_Z = 5.0
#: ... and beyond this amplitude (px): a smaller bias moves a COR by less than DIC's white noise does
FLOOR_PX = 5e-4
#: ... and only where the body's displacement sweeps this many pixels (peak to peak) over the fitted frames: on
#: fewer, b(d) is a smooth function of the motion itself and the motion model would be fitted with it
MIN_SWEEP_PX = 3.0
#: fewer frames in a flight: left out of the ball's fit (a cubic needs room)
MIN_FLIGHT_FRAMES = 8


@dataclass(frozen=True)
class _Projected:
    """The bias columns and the displacements with every motion block projected out, and the dof it used."""

    columns: np.ndarray
    values: np.ndarray
    raw_values: np.ndarray
    model_dof: int


def _project_blocks(blocks: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> _Projected | None:
    """Stack (S - P S, y - P y) over blocks (motion design M, bias columns S, values y), P M's projector."""
    cols, vals, raw, dof = [], [], [], 0
    for M, S, y in blocks:
        Q, _ = np.linalg.qr(M)
        cols.append(S - Q @ (Q.T @ S))
        vals.append(y - Q @ (Q.T @ y))
        raw.append(y)
        dof += M.shape[1]
    if not cols:
        return None
    return _Projected(np.vstack(cols), np.concatenate(vals), np.concatenate(raw), dof)


def _body_fit(body: str, proj: _Projected | None, sweep_px: float, mm_per_px: float) -> BodyBias:
    """The S-curve's least squares on the projected blocks, and whether to take it out (:func:`decide`)."""
    if proj is None or proj.values.size <= proj.model_dof + proj.columns.shape[1] + 10:
        return BodyBias(body, reason="too few frames to fit it", sweep_px=sweep_px)
    S, r = proj.columns, proj.values
    coef, *_ = np.linalg.lstsq(S, r, rcond=None)
    resid = r - S @ coef
    dof = r.size - proj.model_dof - S.shape[1]
    s2 = float(resid @ resid) / dof
    try:
        cov = s2 * np.linalg.inv(S.T @ S)
    except np.linalg.LinAlgError:
        return BodyBias(body, reason="its columns are singular on these frames", sweep_px=sweep_px)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    a, b = float(coef[0]), float(coef[1])
    amp = math.hypot(a, b)
    # the amplitude's sigma: its gradient through the (a_1, b_1) covariance
    g = np.array([a, b]) / amp if amp > 0 else np.array([1.0, 0.0])
    amp_std = math.sqrt(max(float(g @ cov[:2, :2] @ g), 0.0))
    rms_before = math.sqrt(float(r @ r) / max(r.size - proj.model_dof, 1))
    rms_after = math.sqrt(s2)
    fit = BodyBias(body, coefficients_mm=tuple(map(float, coef)), coefficient_std_mm=tuple(map(float, std)),
                   amplitude_px=amp / mm_per_px, amplitude_std_px=amp_std / mm_per_px, rms_before_mm=rms_before,
                   rms_after_mm=rms_after, frames=int(r.size), sweep_px=sweep_px)
    applied, reason = decide(fit)
    return replace(fit, applied=applied, reason=reason)


def decide(fit: BodyBias) -> tuple[bool, str]:
    """(take it out, why): beyond :data:`MIN_Z` sigmas and :data:`FLOOR_PX`, on a sweep of :data:`MIN_SWEEP_PX`,
    and lowering the residual; else why not."""
    if fit.sweep_px < MIN_SWEEP_PX:
        return False, (f"the {fit.body} sweeps {fit.sweep_px:.1f} px (< {MIN_SWEEP_PX:g}): the bias cannot be told "
                       "from its motion")
    z = fit.amplitude_px / fit.amplitude_std_px if fit.amplitude_std_px > 0 else math.inf
    if not z >= MIN_Z:
        return False, f"{fit.amplitude_px:.1e} px is {z:.1f} sigma (< {MIN_Z:g}): not told from noise"
    if fit.amplitude_px < FLOOR_PX:
        return False, f"{fit.amplitude_px:.1e} px is below the {FLOOR_PX:g} px floor"
    if not fit.rms_after_mm < fit.rms_before_mm:
        return False, "the motion model's residual is not lower with it"
    return True, (f"{fit.amplitude_px:.2e} +- {fit.amplitude_std_px:.1e} px ({z:.0f} sigma): taken out; residual "
                  f"{1e3 * fit.rms_before_mm:.4f} -> {1e3 * fit.rms_after_mm:.4f} um")


def _sweep_px(y_mm: np.ndarray, mm_per_px: float) -> float:
    y = y_mm[np.isfinite(y_mm)]
    return float((np.percentile(y, 99) - np.percentile(y, 1)) / mm_per_px) if y.size else 0.0


def structure_bias(t_s: np.ndarray, y_mm: np.ndarray, frequency_hz: float, mm_per_px: float) -> BodyBias:
    """The structure's S-curve (module docstring: windows with the drive's harmonics) on its finite frames."""
    ok = np.isfinite(t_s) & np.isfinite(y_mm)
    t, y = np.asarray(t_s, dtype=float)[ok], np.asarray(y_mm, dtype=float)[ok]
    if t.size == 0 or not frequency_hz > 0:
        return BodyBias("structure", reason="no structure motion to fit it against")
    w = 2.0 * math.pi * float(frequency_hz)
    edges = np.arange(t[0], t[-1] + STRUCTURE_WINDOW_S, STRUCTURE_WINDOW_S)
    which = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, max(edges.size - 1, 0))

    def blocks():
        for k in np.unique(which):
            sel = which == k
            tt = t[sel] - t[sel].mean()
            if tt.size < 4 * STRUCTURE_HARMONICS + 12:
                continue
            harm = [f(h * w * tt) for h in range(1, STRUCTURE_HARMONICS + 1) for f in (np.sin, np.cos)]
            ramp = [tt * np.sin(w * tt), tt * np.cos(w * tt)]
            M = np.column_stack([np.ones_like(tt), tt, *harm, *ramp])
            yield M, bias_columns(y[sel], mm_per_px, ORDERS), y[sel]

    return _body_fit("structure", _project_blocks(blocks()), _sweep_px(y, mm_per_px), mm_per_px)


def ball_bias(t_s: np.ndarray, y_mm: np.ndarray, flight_frames: Sequence[np.ndarray], mm_per_px: float) -> BodyBias:
    """The ball's S-curve (module docstring: a cubic per free flight) on the flights' finite frames."""
    t_all, y_all = np.asarray(t_s, dtype=float), np.asarray(y_mm, dtype=float)
    finite = np.isfinite(t_all) & np.isfinite(y_all)
    kept = (idx[finite[idx]] for idx in (np.asarray(f, dtype=int) for f in flight_frames))
    used = [idx for idx in kept if idx.size >= MIN_FLIGHT_FRAMES]   # each flight's finite frames

    def blocks():
        for idx in used:
            tau = t_all[idx] - t_all[idx].mean()
            M = np.column_stack([np.ones_like(tau), tau, tau ** 2, tau ** 3])
            yield M, bias_columns(y_all[idx], mm_per_px, ORDERS), y_all[idx]

    sweep = _sweep_px(y_all[np.concatenate(used)], mm_per_px) if used else 0.0
    return _body_fit("ball", _project_blocks(blocks()), sweep, mm_per_px)


def subpixel_bias(track: DicTrack, flight_frames: Sequence[np.ndarray], frequency_hz: float,
                  mm_per_px: float) -> SubpixelBias:
    """Both bodies' S-curves of ``track`` (the structure against the drive at ``frequency_hz``, the ball over the
    free flights' ``flight_frames``, track indices), lost frames left out."""
    good = track.good
    t = np.where(good, track.t_s, np.nan)
    return SubpixelBias(mm_per_px=float(mm_per_px),
                        structure=structure_bias(t, np.where(good, track.structure_mm, np.nan), frequency_hz,
                                                 mm_per_px),
                        ball=ball_bias(t, np.where(good, track.ball_mm, np.nan), flight_frames, mm_per_px))
