"""Deviation D between a simulated and a measured trajectory (paper Eq. 18), the restarted
deviation D_r (the same with the model re-started after each measured impact) and the share of
the per-impact COR variance a COR law explains."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from vibro_model.kinematics import StructureKinematics

from .forces import ForceLaw
from .params import BallCavity
from .restitution import RestitutionLaw


def deviation(t_s, y_sim, y_exp) -> float:
    """D = sqrt( int (y_sim - y_exp)^2 dt / int y_exp^2 dt ), trapezoidal integrals over t_s.

    A fraction (0.03 = 3 %). Any consistent length unit. NaN samples are dropped.
    Raises ValueError for mismatched lengths, fewer than 2 samples, non-increasing
    times, or a measured trajectory that is zero everywhere.
    """
    t = np.asarray(t_s, dtype=float).ravel()
    ys = np.asarray(y_sim, dtype=float).ravel()
    ye = np.asarray(y_exp, dtype=float).ravel()
    if not (t.size == ys.size == ye.size):
        raise ValueError(f"deviation: lengths differ (t {t.size}, y_sim {ys.size}, y_exp {ye.size})")
    keep = np.isfinite(t) & np.isfinite(ys) & np.isfinite(ye)
    t, ys, ye = t[keep], ys[keep], ye[keep]
    if t.size < 2:
        raise ValueError("deviation: need at least 2 finite samples")
    if np.any(np.diff(t) <= 0):
        raise ValueError("deviation: times must increase")
    den = np.trapezoid(ye ** 2, t)
    if den <= 0:
        raise ValueError("deviation: the measured trajectory is zero everywhere (D undefined)")
    return float(np.sqrt(np.trapezoid((ys - ye) ** 2, t) / den))


@dataclass(frozen=True)
class Restart:
    """One restarted flight (SI, the frame of the measured positions): the measured ball position
    ``y_m`` and velocity ``v_mps`` just after the impact at ``t_start_s`` that opens the flight; the
    flight is compared with the measurement on the frames in [t_start_s, t_end_s] (t_end_s: the
    measured impact that closes it, or its last frame)."""

    t_start_s: float
    t_end_s: float
    y_m: float
    v_mps: float


@dataclass
class RestartedRun:
    """Result of :func:`restarted_deviation`: D_r and the compared samples (frames inside a window)."""

    deviation: float
    t_s: np.ndarray
    simulated_m: np.ndarray
    measured_m: np.ndarray
    n_flights: int


def restarted_deviation(t_s, y_exp_m, restarts: Sequence[Restart], structure: StructureKinematics,  # noqa: PLR0913
                        cavity: BallCavity, restitution: RestitutionLaw, force: ForceLaw | None = None,
                        frame_offset_m: float = 0.0, plates=None) -> RestartedRun:
    """D_r: the deviation of Eq. 18 with the model re-started from the measured state after each impact.

    Each flight k is simulated with the exact COR model (:func:`vibro_sim.cor_model.simulate_cor`,
    the model's structure motion, cavity, flight force and COR law) from its measured post-impact
    state (``restarts[k]``: time, position, velocity) to the end of its window, so a model error
    shows within each flight but the per-impact COR scatter of a real rig (every impact its own COR)
    does not accumulate from impact to impact, as it does in the free-running D of Eq. 18. The
    measured post-impact velocity replays each measured COR: D_r judges the flight law and the
    structure motion, not the COR law (a COR law's quality is its share of the per-impact COR
    variance, :func:`cor_variance_share`).

        D_r = sqrt( sum_k int_{window k} (y_sim - y_exp)^2 dt / sum_k int_{window k} y_exp^2 dt )

    with trapezoidal integrals over the frames of each window: Eq. 18's normalisation (the
    measured displacement) over the same frames, so D_r and D are fractions on one scale
    (0.03 = 3 %). For a correct model D_r is set by the measurement noise alone: about
    sqrt(sigma^2 + start-state error^2) / RMS(y_exp), sigma the per-frame position noise.

    ``t_s``/``y_exp_m``: measured frame times (s) and ball positions (m, any frame of reference in
    which ``y_exp + frame_offset_m`` is the lab frame of ``structure``: ball minus cavity centre =
    y_exp + frame_offset_m - Y_s(t)). Restart positions are in the measured frame and are put inside
    the free play if the measurement places them (by noise) just outside. ``plates``: plates that move against the
    structure (:func:`vibro_sim.cor_model.simulate_cor`'s), the free play then between them. Windows with fewer than 2
    frames are skipped. Raises ValueError when no window has 2 frames or the measured displacement
    is zero over the windows.
    """
    from .cor_model import simulate_cor

    t = np.asarray(t_s, dtype=float).ravel()
    y = np.asarray(y_exp_m, dtype=float).ravel()
    if t.size != y.size:
        raise ValueError(f"restarted_deviation: lengths differ (t {t.size}, y_exp {y.size})")
    b = cavity.free_play_m
    num = den = 0.0
    ts, sims, meas = [], [], []
    n = 0
    for r in restarts:
        sel = (t >= r.t_start_s) & (t <= r.t_end_s) & np.isfinite(y)
        if sel.sum() < 2 or r.t_end_s <= r.t_start_s:
            continue
        tk, yk = t[sel], y[sel]
        y_s0 = float(structure.position(r.t_start_s))
        top, bottom = (float((plates or {}).get(p, structure).position(r.t_start_s)) - y_s0 for p in ("top", "bottom"))
        rel = min(max(r.y_m + frame_offset_m - y_s0, bottom - b * (1 - 1e-9)), top + b * (1 - 1e-9))
        res = simulate_cor(structure, cavity, restitution, force, y0_m=y_s0 + rel, v0_mps=r.v_mps, t0_s=r.t_start_s,
                           t_end_s=float(tk[-1]), plates=plates)
        sim = np.asarray(res.sample(tk), dtype=float) - frame_offset_m
        num += float(np.trapezoid((sim - yk) ** 2, tk))
        den += float(np.trapezoid(yk ** 2, tk))
        ts.append(tk)
        sims.append(sim)
        meas.append(yk)
        n += 1
    if n == 0:
        raise ValueError("restarted_deviation: no flight window holds 2 frames")
    if den <= 0:
        raise ValueError("restarted_deviation: the measured trajectory is zero over the windows (D_r undefined)")
    return RestartedRun(float(math.sqrt(num / den)), np.concatenate(ts), np.concatenate(sims), np.concatenate(meas), n)


def cor_variance_share(cor, cor_law, noise_var: float, n_law_parameters: int) -> float | None:
    """Share of the per-impact COR variance a COR law explains beyond the measurement noise.

    ``cor``: the measured CORs e_i (Eq. 16); ``cor_law``: the law's prediction for each impact;
    ``noise_var``: the mean variance of the COR measurement (cor_std^2 of the identification);
    ``n_law_parameters``: parameters of the law (the constant-COR baseline has 1). With unbiased
    variances s0^2 = sum (e - mean e)^2 / (n - 1) (the constant-COR baseline) and
    s1^2 = sum (e - law)^2 / (n - p),

        share = (s0^2 - s1^2) / (s0^2 - noise_var)

    i.e. the adjusted R^2 of the law against the constant COR, counting only the variance the
    measurement noise does not give. ~1: the law explains all real scatter; ~0 (within about
    +-(F - 1) / (n - 2) for a law that explains nothing, F the F-test's statistic): it explains
    none. None when fewer than p + 2 impacts or the COR varies no more than its noise (nothing to
    explain).
    """
    e = np.asarray(cor, dtype=float).ravel()
    pred = np.asarray(cor_law, dtype=float).ravel()
    n, p = e.size, int(n_law_parameters)
    if pred.size != n:
        raise ValueError(f"cor_variance_share: {n} CORs but {pred.size} predictions")
    if n < p + 2 or p < 1:
        return None
    s0 = float(np.sum((e - e.mean()) ** 2)) / (n - 1)
    s1 = float(np.sum((e - pred) ** 2)) / (n - p)
    real = s0 - max(float(noise_var), 0.0)
    if not real > 0:
        return None
    return float((s0 - s1) / real)
