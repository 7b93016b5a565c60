"""A located structure tone, modelled (closing the loop for an out-of-catalogue mismatch).

When the systematic-mismatch analysis (:mod:`.systematic`) locates a periodic structure residual at a
frequency that is not a drive harmonic (another mode, a beat: no catalogue term), the tone is not a
catalogue effect (the finding stays ``unexplained``) but it is a known function of time, so it can
correct the measurement: the structure velocity at each impact (paper Eq. 16) includes it.

The model: the chain's structure model (B + drive harmonics ``orders``) plus one sinusoid

    Y_s(t) += a sin(2 pi f_T t) + b cos(2 pi f_T t) = A sin(2 pi f_T t + phi),  A = hypot(a, b), phi = atan2(b, a)

(t the camera time, s; A in m) fitted jointly by least squares on the structure track
(:func:`fit_structure_tone`: linear in the coefficients, the drive and tone frequencies refined by
variable projection within +-0.2 % of the drive and +-1/T of the located tone), with the covariance of
every parameter from the Gauss-Newton Jacobian (sigma^2 (J^T J)^-1, sigma^2 = sse / dof), which for a
tone in white noise is the Cramer-Rao bound (sd(f_T) = sqrt(6) sigma / (pi A sqrt(N) T),
sd(A) = sigma sqrt(2 / N)).

Whether it is modelled (:func:`tone_f_test`) is decided by an F-test of the extra sinusoid against the
residual noise of the fit with it, corrected for the search that chose its frequency (the false-alarm
probability of the best periodogram peak, Baluev 2008: see :func:`search_false_alarm`). Only
the strongest located tone that passes is modelled (a second one stays located, unmodelled). When the
identification found the drive not stationary (results.json ``drive``), nothing within the drive's band is a tone:
it is the drive's amplitude or frequency moving (:func:`.systematic.drive_patterns`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import StructureModelFit, _design
from vibro_discrepancy.systematic import ALPHA_FAMILY, Mismatch, in_drive_band
from vibro_model.codec import json_number as _num
from vibro_model.kinematics import StructureWithTone
from vibro_model.tail_probability import f_sf

#: the name of the modelled tone (the synthetic rig's invented effect of the same physics), used as the
#: impacts' ``cor_method`` part when it corrects them
TONE_EFFECT = "structure_tone"
#: the ``unexplained`` finding's parameters when a tone is modelled (the synth's names and units)
TONE_PARAMETERS = ("tone_frequency_hz", "tone_amplitude_um", "tone_phase_rad")
REFINE_PASSES = 3
POLISH_STEPS = 6
DRIVE_SPAN = 2e-3            # the drive frequency is refined within +-0.2 % (as fit_structure_harmonics)


@dataclass(kw_only=True)
class StructureToneFit(StructureModelFit):
    """The structure model plus one tone: ``coefs`` = [B, a_k, b_k ..., a_T, b_T] (the tone's sine and
    cosine coefficients last, m), ``tone_hz`` its frequency; parameters [coefs..., f, f_T]."""

    tone_hz: float = 0.0
    n_frequencies = 2

    @property
    def tone_coefs(self) -> tuple[float, float]:
        return float(self.coefs[-2]), float(self.coefs[-1])

    @property
    def tone_amplitude_m(self) -> float:
        return math.hypot(*self.tone_coefs)

    @property
    def tone_phase_rad(self) -> float:
        a, b = self.tone_coefs
        return math.atan2(b, a)

    def label_terms(self) -> list[str]:
        return super().label_terms() + [f"{TONE_EFFECT}({self.tone_hz:.3f} Hz)"]

    def motion(self) -> StructureWithTone:
        return StructureWithTone(**super().motion().to_dict(), tone_amplitude_m=self.tone_amplitude_m,
                                 tone_frequency_hz=self.tone_hz, tone_phase_rad=self.tone_phase_rad)

    def parameters(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.coefs, dtype=float), [self.frequency_hz, self.tone_hz]])

    def velocity_with(self, params: np.ndarray, t_s: float) -> float:
        base = np.append(params[:-4], params[-2])
        a, b, w = params[-4], params[-3], 2 * math.pi * params[-1]
        return super().velocity_with(base, t_s) + w * (a * math.cos(w * t_s) - b * math.sin(w * t_s))

    def jacobian(self, t_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        base = StructureModelFit.jacobian(self, t)        # [design of B + harmonics, d/df]
        a, b = self.tone_coefs
        w = 2 * math.pi * self.tone_hz
        s, c = np.sin(w * t), np.cos(w * t)
        d_ft = 2 * math.pi * t * (a * c - b * s)
        return np.column_stack([base[:, :-1], s, c, base[:, -1], d_ft])


def _tone_design(t: np.ndarray, f_hz: float, orders: Sequence[int], tone_hz: float) -> np.ndarray:
    w = 2 * math.pi * tone_hz
    return np.column_stack([_design(t, f_hz, orders), np.sin(w * t), np.cos(w * t)])


def fit_structure_tone(t_s: np.ndarray, y_m: np.ndarray, f0_hz: float, orders: Sequence[int], tone_hz: float,
                       tone_halfwidth_hz: float) -> StructureToneFit:
    """Least squares of the structure track (m) with the drive harmonics ``orders`` and one tone near
    ``tone_hz`` (within +-``tone_halfwidth_hz``); the drive frequency refined within +-0.2 % of ``f0_hz``
    (alternating 1-D searches: the two frequencies are nearly orthogonal once T >> 1 / |f0 - f_T|), then
    Gauss-Newton on every parameter to the optimum (:func:`_polish`)."""
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y_m, dtype=float)
    orders = tuple(sorted(set((1,) + tuple(orders))))

    def sse(f: float, ft: float) -> float:
        X = _tone_design(t, f, orders, ft)
        c, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ c
        return float(r @ r)

    f, ft = float(f0_hz), float(tone_hz)
    span = DRIVE_SPAN * f0_hz
    for _ in range(REFINE_PASSES):
        f = float(minimize_scalar(lambda x: sse(x, ft), bounds=(f0_hz - span, f0_hz + span), method="bounded",
                                  options={"xatol": 1e-9 * f0_hz}).x)
        ft = float(minimize_scalar(lambda x: sse(f, x), bounds=(tone_hz - tone_halfwidth_hz,
                                                                tone_hz + tone_halfwidth_hz),
                                   method="bounded", options={"xatol": 1e-7 * tone_halfwidth_hz}).x)
    X = _tone_design(t, f, orders, ft)
    c, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ c
    n = t.size
    fit = StructureToneFit(orders=orders, frequency_hz=f, coefs=c, sse=float(r @ r), n_points=n,
                           dof=max(n - X.shape[1] - 2, 1), residual=r, tone_hz=ft)
    return _polish(fit, t, y)


def _with_parameters(fit: StructureToneFit, p: np.ndarray, t: np.ndarray, y: np.ndarray) -> StructureToneFit:
    X = _tone_design(t, float(p[-2]), fit.orders, float(p[-1]))
    r = y - X @ p[:-2]
    return StructureToneFit(orders=fit.orders, frequency_hz=float(p[-2]), coefs=p[:-2].copy(), sse=float(r @ r),
                            n_points=fit.n_points, dof=fit.dof, residual=r, tone_hz=float(p[-1]))


def _polish(fit: StructureToneFit, t: np.ndarray, y: np.ndarray, steps: int = POLISH_STEPS) -> StructureToneFit:
    """Gauss-Newton on every parameter from the 1-D searches' optimum, to the least-squares optimum itself
    (to rounding: the same data give the same fit whatever the starting frequencies, so the graph's node
    and ``vibro analyze`` agree to 1e-9)."""
    for _ in range(steps):
        dp, *_ = np.linalg.lstsq(fit.jacobian(t), fit.residual, rcond=None)
        trial = _with_parameters(fit, fit.parameters() + dp, t, y)
        if not trial.sse < fit.sse:
            break
        fit = trial
    return fit


@dataclass(frozen=True, kw_only=True)
class ToneTest:
    """The test of one tone against the residual noise (:func:`tone_f_test`)."""

    frequency_hz: float
    f_statistic: float
    dof: tuple[int, int]
    p_value: float                 # the F-test at one given frequency
    frequencies_searched: int      # independent frequencies in the band searched, (f_hi - f_lo) T
    p_family: float                # false-alarm probability of the best peak of the search (Baluev 2008)
    alpha: float
    accepted: bool

    def to_dict(self) -> dict:
        return {"frequency_hz": _num(self.frequency_hz), "f_statistic": _num(self.f_statistic),
                "dof": list(self.dof), "p_value": _num(self.p_value),
                "frequencies_searched": self.frequencies_searched, "p_family": _num(self.p_family),
                "alpha": self.alpha, "accepted": self.accepted}


def search_false_alarm(z: float, n_null_dof: int, frequencies_searched: int, t_s: np.ndarray) -> float:
    """False-alarm probability of the highest peak of a least-squares periodogram searched continuously
    over a band of ``frequencies_searched`` / T Hz, the noise variance estimated from the residual
    (Baluev 2008, MNRAS 385, 1279, eq. 5-6 in the normalisation z = (SSE0 - SSE1) / SSE0, as
    astropy.timeseries' ``fap_baluev``): FAP = 1 - (1 - p1) exp(-tau), p1 = (1 - z)^(N_K / 2) the F-test's
    p-value at one frequency, tau = gamma(N_H) W (1 - z)^((N_K - 1) / 2) sqrt(N_H z / 2), W = band x
    T_eff, T_eff = sqrt(4 pi var(t)), N_H = ``n_null_dof`` the residual degrees of freedom without the
    tone, N_K = N_H - 2. A grid of M = band x T "independent" frequencies (Bonferroni, M p1) undercounts a
    search refined between grid points: on white noise its p < 1e-3 came out ~2.5x too often."""
    from scipy.special import gammaln

    nh = int(n_null_dof)
    nk = nh - 2
    if nk <= 1 or not 0.0 <= z < 1.0:
        return 0.0 if z >= 1.0 else 1.0
    t = np.asarray(t_s, dtype=float)
    T = float(t.max() - t.min())
    t_eff = math.sqrt(4 * math.pi * float(np.var(t)))
    W = frequencies_searched / T * t_eff
    gamma = math.sqrt(2.0 / nh) * math.exp(gammaln(nh / 2.0) - gammaln((nh - 1) / 2.0))
    p1 = (1.0 - z) ** (0.5 * nk)
    tau = gamma * W * (1.0 - z) ** (0.5 * (nk - 1)) * math.sqrt(0.5 * nh * z)
    return float(min(1.0, max(0.0, -math.expm1(math.log1p(-min(p1, 1.0 - 1e-16)) - tau))))


def tone_f_test(sse_without_m2: float, fit: StructureToneFit, frequencies_searched: int, t_s: np.ndarray,
                alpha: float = ALPHA_FAMILY) -> ToneTest:
    """Test of the tone of ``fit`` against the same structure model without it (``sse_without_m2``, on
    the same samples ``t_s``): F = ((SSE0 - SSE1) / 2) / (SSE1 / dof1), 2 numerator degrees of freedom
    (the tone's sine and cosine coefficients), dof1 the residual degrees of freedom with the tone. Its
    frequency was not given but chosen as the best of a search over ``frequencies_searched`` independent
    frequencies, so the decision uses the search's false-alarm probability (:func:`search_false_alarm`,
    Baluev 2008), not the single-frequency p-value. The tone is modelled when that probability is below
    ``alpha``, the family-wise false-alarm probability of the systematic analysis
    (:data:`.systematic.ALPHA_FAMILY` = 1e-3): on recordings without a tone, at most about one in a
    thousand gets one modelled. The variance is the residual's own (not the 5th-difference floor): a
    residual that is not white, or a model that misses something else, inflates it and makes the test
    conservative."""
    dof1 = int(fit.dof)
    sse0 = float(sse_without_m2)
    drop = max(sse0 - float(fit.sse), 0.0)
    F = (drop / 2.0) / (fit.sse / dof1) if fit.sse > 0 else math.inf
    p = f_sf(F, 2, dof1) if math.isfinite(F) else 0.0
    m = max(int(frequencies_searched), 1)
    z = drop / sse0 if sse0 > 0 else 0.0
    fap = search_false_alarm(z, dof1 + 2, m, t_s)
    return ToneTest(frequency_hz=float(fit.tone_hz), f_statistic=F, dof=(2, dof1), p_value=p, frequencies_searched=m,
                    p_family=fap, alpha=alpha, accepted=bool(fap < alpha))


def frequencies_searched(t_s: np.ndarray, f_lo_hz: float, f_hi_hz: float) -> int:
    """Independent frequencies in [f_lo, f_hi] over the span of ``t_s``: (f_hi - f_lo) T."""
    T = float(np.max(t_s) - np.min(t_s))
    return max(1, int(round((f_hi_hz - f_lo_hz) * T)))


@dataclass
class ToneModel:
    """A modelled tone: the structure fit with it, its test and the located mismatch it models."""

    fit: StructureToneFit
    test: ToneTest
    located: Mismatch
    rms_before_m: float
    stds: dict[str, float] = field(default_factory=dict)   # frequency_hz, amplitude_m, phase_rad

    def parameters(self) -> dict[str, float]:
        """The ``unexplained`` finding's parameters (:data:`TONE_PARAMETERS`)."""
        return {"tone_frequency_hz": self.fit.tone_hz, "tone_amplitude_um": self.fit.tone_amplitude_m * 1e6,
                "tone_phase_rad": self.fit.tone_phase_rad}

    def parameter_stds(self) -> dict[str, float]:
        return {"tone_frequency_hz": self.stds["frequency_hz"], "tone_amplitude_um": self.stds["amplitude_m"] * 1e6,
                "tone_phase_rad": self.stds["phase_rad"]}

    def to_dict(self) -> dict:
        """The finding's ``model`` entry."""
        p, sd = self.parameters(), self.parameter_stds()
        return {TONE_EFFECT: {
            "frequency_hz": _num(p["tone_frequency_hz"]), "frequency_std_hz": _num(sd["tone_frequency_hz"]),
            "amplitude_um": _num(p["tone_amplitude_um"]), "amplitude_std_um": _num(sd["tone_amplitude_um"]),
            "phase_rad": _num(p["tone_phase_rad"]), "phase_std_rad": _num(sd["tone_phase_rad"]),
            "convention": "Y_s += amplitude sin(2 pi frequency t + phase), t the camera time (s)",
            "structure_rms_before_um": _num(self.rms_before_m * 1e6),
            "structure_rms_after_um": _num(math.sqrt(self.fit.sse / max(self.fit.n_points, 1)) * 1e6),
            "f_test": self.test.to_dict(),
            "used_for": "the structure velocity at each impact (impacts[].cor; cor_paper beside)"}}

    def words(self) -> str:
        p, sd = self.parameters(), self.parameter_stds()
        return (f"modelled: structure tone {p['tone_amplitude_um']:.3g} +- {sd['tone_amplitude_um']:.2g} um at "
                f"{p['tone_frequency_hz']:.4f} +- {sd['tone_frequency_hz']:.2g} Hz (F = {self.test.f_statistic:.3g}, "
                f"false-alarm probability over {self.test.frequencies_searched} frequencies "
                f"{self.test.p_family:.1e}), used for the structure velocity at the impacts")


@dataclass
class ToneDecision:
    """What was done with the located structure tones: the modelled one (or None) and every test."""

    model: ToneModel | None
    tests: list[ToneTest]

    def to_dict(self) -> dict:
        return {"modelled": self.model is not None, "tests": [t.to_dict() for t in self.tests]}


def _amplitude_phase_stds(fit: StructureToneFit, cov: np.ndarray) -> dict[str, float]:
    """Sd of f_T, A and phi from the covariance of the parameters (first order in a_T, b_T)."""
    a, b = fit.tone_coefs
    A = max(fit.tone_amplitude_m, 1e-300)
    i = len(fit.coefs) - 2
    cab = cov[i:i + 2, i:i + 2]
    gA = np.array([a, b]) / A
    gphi = np.array([-b, a]) / A ** 2
    return {"frequency_hz": math.sqrt(max(float(cov[-1, -1]), 0.0)),
            "amplitude_m": math.sqrt(max(float(gA @ cab @ gA), 0.0)),
            "phase_rad": math.sqrt(max(float(gphi @ cab @ gphi), 0.0))}


def tone_model(meas: Measured, structure: StructureModelFit, located: Mismatch, searched: int,
               alpha: float = ALPHA_FAMILY) -> tuple[ToneModel | None, ToneTest]:
    """The joint fit of ``structure``'s model plus the ``located`` tone on the structure track, and its
    F-test (``searched``: the frequencies the search tried); the model when the test accepts it."""
    T = float(meas.t_s[-1] - meas.t_s[0])
    fit = fit_structure_tone(meas.t_s, meas.structure_m, structure.frequency_hz, structure.orders,
                             float(located.frequency_hz), 1.0 / T)
    test = tone_f_test(structure.sse, fit, searched, meas.t_s, alpha)
    if not test.accepted:
        return None, test
    stds = _amplitude_phase_stds(fit, fit.covariance(meas.t_s))
    rms0 = math.sqrt(structure.sse / max(structure.n_points, 1))
    return ToneModel(fit, test, located, rms0, stds), test


def model_structure_tone(meas: Measured, structure: StructureModelFit, patterns: Sequence[Mismatch],
                         fps: float, alpha: float = ALPHA_FAMILY) -> ToneDecision:
    """The strongest located periodic structure mismatch (:mod:`.systematic`) that passes
    :func:`tone_f_test`, modelled with ``structure`` (the chain's current structure fit on the same track);
    the number of frequencies searched is the search's own (else the band 1.5/T .. fps/2 it uses). A drive that did
    not hold still (``meas.drive``) has no tone within its band (:func:`.systematic.in_drive_band`): those side
    bands are the drive changing, never modelled as a tone."""
    tones = sorted((m for m in patterns if m.series == "structure" and m.shape == "periodic"
                    and m.frequency_hz is not None and not in_drive_band(m.frequency_hz, meas)),
                   key=lambda m: -abs(m.size))
    tests = []
    T = float(meas.t_s[-1] - meas.t_s[0])
    for m in tones:
        searched = m.frequencies_searched or frequencies_searched(meas.t_s, 1.5 / T, 0.5 * fps)
        model, test = tone_model(meas, structure, m, searched, alpha)
        tests.append(test)
        if model is not None:
            return ToneDecision(model, tests)
    return ToneDecision(None, tests)


def modelled_tone(finding) -> bool:
    """Whether a finding (contract mapping or object with ``effect``/``parameters``) is an ``unexplained``
    entry with a modelled structure tone (its parameters carry :data:`TONE_PARAMETERS`)."""
    effect = finding.get("effect") if isinstance(finding, dict) else getattr(finding, "effect", None)
    params = finding.get("parameters") if isinstance(finding, dict) else getattr(finding, "parameters", None)
    return effect == "unexplained" and bool(params) and all(params.get(k) is not None for k in TONE_PARAMETERS)
