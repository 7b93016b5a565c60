"""A plate that moves against the tracked structure: measured from where the ball meets it, taken into the CORs.

DIC tracks the structure at one place (the ROI); Eq. 16 takes the plate's velocity at an impact to be that
structure's. A plate can move against it over a take: a screw backing off, a mount relaxing, a plate creeping
under load. Where the ball meets a plate, the ball's centre is on it, so the contact level (ball minus
structure at the impact time, :attr:`vibro_fit.impacts.ImpactFit.y_rel_mm`) is the plate's height against the
tracked structure, measured at every impact to about 0.1 um on rendered recordings. A plate that creeps at
r um/s moves r faster than the structure at each of its impacts; Eq. 16 with the structure's velocity then
misses the COR by (1 + e) r / |v_rel| (at r = 40 um/s and 0.6 m/s, 1.1e-4: several sigmas, all of one sign).

:func:`plate_motion` fits each plate's contact levels against time with a polynomial (degree 0-3, chosen by
BIC) and with a single step (the plate moved once: a loosening screw; its velocity is the structure's away
from the step, so the CORs need no change). The creep is taken into the CORs (:func:`moved_impact`: the plate's
velocity = the structure's + the fitted level's derivative, its uncertainty propagated into ``cor_std``) only
where all of these hold:

- at least :data:`MIN_IMPACTS` impacts on the plate;
- a smooth model beats the step by BIC, and beats the constant level by BIC;
- the mean rate is at least :data:`RATE_SIGMAS` sigmas from zero (the sigma from the level residuals);
- a physical floor: it moves some impact's COR by at least :data:`COR_FLOOR_OF_SIGMA` of the median noise part
  of the plate's COR sigmas (:func:`noise_sigma`; a creep of noise size over a 20,000-frame take is significant
  and changes nothing).

Otherwise :class:`PlateMotion` says what was seen and why nothing was changed. Units: times s, levels um,
rates um/s, velocities m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vibro_io.plate_motion import creep_velocity_mps
from vibro_model.model_error import cor_variance_of_biases

from .impacts import ImpactFit

#: fewest impacts on a plate to measure its motion
MIN_IMPACTS = 8
#: highest polynomial degree of a creep
MAX_DEGREE = 3
#: the mean rate must be this many sigmas from zero
RATE_SIGMAS = 5.0
#: the correction must move some COR by this fraction of the plate's median cor_std
COR_FLOOR_OF_SIGMA = 0.2
#: fewest impacts on each side of a step
STEP_MIN_SIDE = 3
#: a contact level this many robust sigmas from the levels' model is left out (a mis-segmented impact)
OUTLIER_SIGMAS = 5.0


@dataclass(frozen=True)
class PlateMotion:
    """One plate's height against the tracked structure over the take, and whether the CORs took it in.

    ``shape``: ``"still"`` (no motion beyond the floors), ``"creep"`` (a smooth drift: ``coef_um`` the
    polynomial of the level in um against t - ``t_ref_s``, highest power first, ``cov_um`` its covariance),
    ``"step"`` (it moved once: ``step_um`` at ``step_time_s``) or ``"too_few"`` impacts. ``applied`` says whether
    the impacts on it were re-measured with its velocity; ``reason`` says why or why not."""

    plate: str
    shape: str
    n_impacts: int
    applied: bool
    reason: str
    t_ref_s: float = 0.0
    coef_um: tuple[float, ...] = (0.0,)
    cov_um: tuple[tuple[float, ...], ...] = ((0.0,),)
    rate_um_per_s: float = 0.0
    rate_std_um_per_s: float = 0.0
    travel_um: float = 0.0
    level_rms_um: float = 0.0
    step_um: float = 0.0
    step_time_s: float | None = None
    cor_shift_max: float = 0.0
    levels_left_out: int = 0      # contact levels left out as outliers (:func:`level_outliers`)

    def velocity_mps(self, t_s: float) -> tuple[float, float]:
        """(velocity, its std) of the plate against the tracked structure at t_s (m/s): the level's derivative."""
        coef, cov = np.asarray(self.coef_um, float), np.asarray(self.cov_um, float)
        deg = coef.size - 1
        if deg < 1:
            return 0.0, 0.0
        x = t_s - self.t_ref_s
        grad = np.array([(deg - k) * x ** (deg - k - 1) if deg - k >= 1 else 0.0 for k in range(deg + 1)])
        return creep_velocity_mps(coef, self.t_ref_s, t_s), 1e-6 * float(np.sqrt(max(grad @ cov @ grad, 0.0)))

    def to_dict(self) -> dict:
        """The results.json ``plate_motion`` entry of this plate (docs/recording-format.md)."""
        out = {"shape": self.shape, "applied": self.applied, "impacts": self.n_impacts, "reason": self.reason,
               "levels_left_out": self.levels_left_out}
        if self.shape in ("still", "creep"):
            out.update(rate_um_per_s=self.rate_um_per_s, rate_std_um_per_s=self.rate_std_um_per_s,
                       travel_um=self.travel_um, level_rms_um=self.level_rms_um, cor_shift_max=self.cor_shift_max)
        if self.shape == "creep":
            out.update(t_ref_s=self.t_ref_s, coef_um=list(self.coef_um), degree=len(self.coef_um) - 1)
        if self.shape == "step":
            out.update(step_um=self.step_um, step_time_s=self.step_time_s, level_rms_um=self.level_rms_um)
        return out


def contact_levels(impacts: list[ImpactFit], plate: str) -> tuple[np.ndarray, np.ndarray]:
    """(times s, levels um) of the paper impacts on ``plate`` with a measured contact level, in time order (an
    impact found inside a run of lost frames left out: its level rests on flights that stop short of it)."""
    rows = sorted((float(i.t_s), 1e3 * float(i.y_rel_mm)) for i in impacts
                  if i.plate == plate and i.method == "paper" and i.t_s is not None and not i.in_gap
                  and math.isfinite(float(i.t_s)) and math.isfinite(float(getattr(i, "y_rel_mm", math.nan))))
    if not rows:
        return np.zeros(0), np.zeros(0)
    t, y = np.array(rows).T
    return t, y


def _bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a least-squares fit with k parameters (Gaussian errors)."""
    return n * math.log(max(rss, 1e-300) / n) + k * math.log(n)


def fit_polynomial(t: np.ndarray, y: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares polynomial of ``degree`` in t - mean(t): (coefficients highest first, covariance from the
    residual variance, residual sum of squares)."""
    x = t - t.mean()
    A = np.vander(x, degree + 1)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    rss = float(r @ r)
    dof = max(t.size - degree - 1, 1)
    cov = rss / dof * np.linalg.pinv(A.T @ A)
    return coef, cov, rss


def best_step(t: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """The single step that fits best: (residual sum of squares, step size, step time midway between the impacts
    on either side), each side at least :data:`STEP_MIN_SIDE` impacts; (inf, 0, nan) when too few."""
    n = y.size
    if n < 2 * STEP_MIN_SIDE:
        return math.inf, 0.0, math.nan
    c1, c2 = np.cumsum(y), np.cumsum(y * y)
    k = np.arange(STEP_MIN_SIDE, n - STEP_MIN_SIDE + 1)
    left = c2[k - 1] - c1[k - 1] ** 2 / k
    right = (c2[-1] - c2[k - 1]) - (c1[-1] - c1[k - 1]) ** 2 / (n - k)
    j = int(np.argmin(left + right))
    kk = int(k[j])
    step = float(y[kk:].mean() - y[:kk].mean())
    return float(left[j] + right[j]), step, float(0.5 * (t[kk - 1] + t[kk]))


def cor_shift(imp: ImpactFit, v_plate_mps: float) -> float | None:
    """The COR (Eq. 16) of ``imp`` with the plate moving v_plate (m/s) faster than the structure; None when the
    impact has no COR or no velocities."""
    vals = (imp.cor, imp.v_ball_before_mps, imp.v_ball_after_mps, imp.v_structure_mps)
    if any(v is None or not math.isfinite(float(v)) for v in vals):
        return None
    vb, va, vs = float(imp.v_ball_before_mps), float(imp.v_ball_after_mps), float(imp.v_structure_mps) + v_plate_mps
    rel = vb - vs
    if rel == 0.0:
        return None
    return -(va - vs) / rel


def noise_sigma(imp: ImpactFit) -> float:
    """The part of ``imp``'s COR sigma that is measurement noise: cor_std without its model-error share
    (``cor_std_model``, :mod:`vibro_fit.model_error`); NaN when unknown. The floor is set against it: the paper
    model's misfit (a drag it leaves out) widens cor_std, and a model that takes the misfit in (the discrepancy
    analysis' re-measured CORs) is left with the noise."""
    if imp.cor_std is None or not math.isfinite(float(imp.cor_std)):
        return math.nan
    model = float(imp.cor_std_model) if imp.cor_std_model is not None else 0.0
    return math.sqrt(max(float(imp.cor_std) ** 2 - model ** 2, 0.0))


def _level_models(t: np.ndarray, y: np.ndarray) -> tuple[dict, dict, int, tuple[float, float, float], float]:
    """The polynomial fits of degree 0..:data:`MAX_DEGREE` ({degree: fit_polynomial}), their BICs, the best degree,
    the best single step (:func:`best_step`) and its BIC."""
    n = t.size
    fits = {d: fit_polynomial(t, y, d) for d in range(0, min(MAX_DEGREE, n - 3) + 1)}
    bics = {d: _bic(f[2], n, d + 1) for d, f in fits.items()}
    step = best_step(t, y)
    return fits, bics, min(bics, key=bics.get), step, _bic(step[0], n, 3) if math.isfinite(step[0]) else math.inf


def level_outliers(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Contact levels more than :data:`OUTLIER_SIGMAS` robust sigmas (1.4826 MAD) from the better of the best
    polynomial and the best step (a level from a mis-segmented impact); a boolean mask."""
    fits, bics, degree, (_, step_um, step_t), step_bic = _level_models(t, y)
    if step_bic < bics[degree]:
        model = np.where(t > step_t, step_um, 0.0)
        model += np.mean(y - model)
    else:
        model = np.polyval(fits[degree][0], t - t.mean())
    r = y - model
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return np.abs(r - np.median(r)) > OUTLIER_SIGMAS * max(sigma, 1e-9)


def plate_motion(impacts: list[ImpactFit], plate: str, levels_from: list[ImpactFit] | None = None) -> PlateMotion:
    """What ``plate`` did against the tracked structure over the take (module docstring): its contact levels from
    the paper impacts ``levels_from`` (default ``impacts``; the ``joint`` method's impacts sit on a fixed level by
    construction), the floor against ``impacts``' CORs."""
    t, y = contact_levels(impacts if levels_from is None else levels_from, plate)
    if t.size < MIN_IMPACTS:
        return _classified(plate, t, y, impacts)
    keep = ~level_outliers(t, y)
    return replace(_classified(plate, t[keep], y[keep], impacts), levels_left_out=int(np.count_nonzero(~keep)))


def _classified(plate: str, t: np.ndarray, y: np.ndarray, impacts: list[ImpactFit]) -> PlateMotion:
    """:func:`plate_motion` on the contact levels ``t`` (s), ``y`` (um) it kept."""
    n = int(t.size)
    if n < MIN_IMPACTS:
        return PlateMotion(plate, "too_few", n, False, f"{n} impacts with a contact level (needs {MIN_IMPACTS})")
    fits, bics, degree, (step_rss, step_um, step_t), step_bic = _level_models(t, y)
    coef, cov, rss = fits[degree]
    t_ref = float(t.mean())
    travel = float(np.polyval(coef, t[-1] - t_ref) - np.polyval(coef, t[0] - t_ref))
    rate, rate_sd = float(fits[1][0][0]), math.sqrt(max(fits[1][1][0, 0], 0.0))   # the mean rate: a line's slope
    base = dict(t_ref_s=t_ref, rate_um_per_s=rate, rate_std_um_per_s=rate_sd, travel_um=travel)
    if step_bic < bics[degree] and step_bic < bics[0]:
        rms = math.sqrt(step_rss / n)
        return PlateMotion(plate, "step", n, False,
                           f"its contact level steps once, {step_um:+.1f} um near t = {step_t:.3f} s (a step fits "
                           "better than a drift: the plate, or the ball's or the structure's track, moved once); away "
                           "from the step the plate moves with the structure, the CORs are unchanged",
                           level_rms_um=rms, step_um=step_um, step_time_s=step_t, **base)
    rms = math.sqrt(rss / n)
    if degree == 0:
        return PlateMotion(plate, "still", n, False, "its height does not drift beyond the contact levels' noise",
                           level_rms_um=rms, **base)
    if abs(rate) < RATE_SIGMAS * rate_sd:
        return PlateMotion(plate, "still", n, False,
                           f"mean rate {rate:+.3f} +- {rate_sd:.3f} um/s is under {RATE_SIGMAS:g} sigma",
                           level_rms_um=rms, **base)
    motion = PlateMotion(plate, "creep", n, True, "", coef_um=tuple(float(c) for c in coef),
                         cov_um=tuple(tuple(float(c) for c in row) for row in cov), level_rms_um=rms, **base)
    shifts, sds = [], []
    for imp in impacts:
        if imp.plate != plate:
            continue
        cor = cor_shift(imp, motion.velocity_mps(float(imp.t_s))[0])
        if cor is not None:
            shifts.append(abs(cor - float(imp.cor)))
            noise = noise_sigma(imp)
            if math.isfinite(noise):
                sds.append(noise)
    largest = max(shifts, default=0.0)
    floor = COR_FLOOR_OF_SIGMA * float(np.median(sds)) if sds else 0.0
    if largest < floor:
        return replace(motion, applied=False, cor_shift_max=largest,
                       reason=(f"creeps {rate:+.2f} +- {rate_sd:.2f} um/s, which moves no COR by more than "
                               f"{largest:.1e} (< {COR_FLOOR_OF_SIGMA:g} x the median COR noise sigma "
                               f"{floor / COR_FLOOR_OF_SIGMA:.1e}): "
                               "left as measured"))
    return replace(motion, cor_shift_max=largest,
                   reason=(f"creeps {rate:+.2f} +- {rate_sd:.2f} um/s (degree {degree}): the impacts on it met a "
                           f"plate that much faster than the structure; CORs re-measured (by up to {largest:.1e})"))


def moved_impact(imp: ImpactFit, motion: PlateMotion) -> ImpactFit:
    """``imp`` with its plate's velocity the structure's plus ``motion``'s (v_structure, cor, cor_paper for a
    paper COR), the rate's uncertainty added to cor_std in quadrature; unchanged where it has no COR."""
    v_plate, v_sd = motion.velocity_mps(float(imp.t_s))
    cor = cor_shift(imp, v_plate)
    if cor is None:
        return imp
    vs = float(imp.v_structure_mps) + v_plate
    var = cor_variance_of_biases(float(imp.v_ball_before_mps), float(imp.v_ball_after_mps), vs, 0.0, 0.0, v_sd ** 2)
    sd = math.sqrt(float(imp.cor_std) ** 2 + var) if imp.cor_std is not None else None
    paper = imp.cor_method in (None, "paper")
    return replace(imp, cor=float(cor), cor_std=sd, v_structure_mps=vs,
                   cor_paper=float(cor) if paper and imp.cor_paper is not None else imp.cor_paper,
                   cor_std_paper=sd if paper and imp.cor_std_paper is not None else imp.cor_std_paper)


def plate_motion_pass(impacts: list[ImpactFit], levels_from: list[ImpactFit] | None = None
                      ) -> tuple[list[ImpactFit], dict[str, PlateMotion]]:
    """The identification's named pass: each plate's motion against the tracked structure (:func:`plate_motion`;
    ``levels_from``: the paper impacts whose contact levels measure it, default ``impacts``), and the impacts with a
    creeping plate's velocity taken into their CORs where it is applied."""
    motions = {p: plate_motion(impacts, p, levels_from) for p in ("top", "bottom")}
    out = [moved_impact(i, motions[i.plate]) if i.plate in motions and motions[i.plate].applied else i
           for i in impacts]
    return out, motions


def plate_motion_notes(motions: dict[str, PlateMotion], method: str) -> list[str]:
    """The warnings of the pass: each creep taken into the CORs; with the ``joint`` method, each plate whose level
    moves (a creep or a step), which that method's fixed-level constraint does not allow for."""
    notes = [f"{m.plate} plate {m.reason}" for m in motions.values() if m.applied]
    if method == "joint":
        notes += [f"{m.plate} plate: its contact level moves {m.step_um if m.shape == 'step' else m.travel_um:+.2f} um "
                  f"over the take ({m.shape}), where the joint method constrains each pair of flights to one fixed "
                  "plate level: its CORs there rest on a level that is not the plate's (method paper does not "
                  "assume it)" for m in motions.values() if m.shape in ("creep", "step")]
    return notes
