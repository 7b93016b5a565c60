"""Does a flight finding fit the shape it claims? The residual force after the chosen model, in the
coordinates the catalogue's terms are written in.

Every catalogue flight term is a force of one shape: Coulomb friction a constant that flips sign with the
direction of motion, a tilt one constant, the drags a function of the speed. A force of another shape (one
that depends on where the ball is in the cavity) is partly absorbed by whichever term correlates best with
it: the deviation falls, the finding would be claimed, and the residual keeps the rest. So before a flight
finding is reported, the extra acceleration is given freedom in the coordinates that separate the shapes:

- **position**: piecewise constant over ``N_BINS`` equal bins of the ball's distance from the lower plate
  (ball - structure, from the model's flights and structure motion, the plate at its impacts' median),
  the same on rising and falling flights;
- **position x direction**: the same bins, with opposite signs on rising and falling flights.

Each is added to the chosen model's own columns (the flights' states free, projected out as in
:func:`~vibro_discrepancy.fitting.fit_flights`, on the model's velocity histories), and counts when it is
significant against the noise floor (chi^2 at ``ALPHA``) and visible (explains ``MIN_EXPLAINED_SIGMA``
noise floors per frame), the rules a catalogue term passes (:mod:`.select`). A structured residual means the
catalogue finding lowers the deviation without fitting the residual's shape: :mod:`.engine` reports it below
``unexplained``, whose words (:meth:`ShapeCheck.words`) name the shape: its direction (towards which
plate), its size against the ball's weight, how it varies with the distance from the plate (with an
exponential's decay length when one fits about as well as the bins) and whether it depends on the
direction of motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import FlightModelFit, _cumtrapz
from vibro_discrepancy.select import ALPHA, MIN_EXPLAINED_SIGMA
from vibro_model.constants import G_MPS2
from vibro_model.kinematics import StructureKinematics
from vibro_model.tail_probability import chi2_sf

N_BINS = 4
DECAYS_MM = tuple(float(x) for x in np.geomspace(0.3, 30.0, 25))   # exponential decay lengths tried
EXP_SHARE = 0.9     # an exponential names the shape when it explains this share of what the bins explain


@dataclass(kw_only=True)
class ShapeCheck:
    """The residual's shape after a flight model (module docstring). ``structured``: a coordinate's columns
    are significant and visible beyond the model's; ``tests``: per coordinate its chi^2, p, explained noise
    floors; the fitted shape: acceleration per position bin (m/s^2, + up) symmetric and direction-odd."""

    structured: bool
    model_terms: tuple[str, ...]
    tests: dict = field(default_factory=dict)
    bin_edges_mm: list[float] = field(default_factory=list)
    accel_even_mps2: list[float] = field(default_factory=list)
    accel_even_std_mps2: list[float] = field(default_factory=list)
    accel_odd_mps2: list[float] = field(default_factory=list)
    direction_dependent: bool = False
    exponential: dict | None = None
    g_mps2: float = G_MPS2

    def to_dict(self) -> dict:
        return {"structured": self.structured, "model": list(self.model_terms), "tests": self.tests,
                "distance_from_lower_plate_bins_mm": self.bin_edges_mm,
                "accel_even_mps2": self.accel_even_mps2, "accel_even_std_mps2": self.accel_even_std_mps2,
                "accel_odd_mps2": self.accel_odd_mps2, "direction_dependent": self.direction_dependent,
                "exponential": self.exponential}

    def words(self) -> str:
        """The shape in plain words, e.g. 'force 25 % of the weight towards the lower plate at contact,
        decaying with the distance from it (over 3.0 mm), independent of the direction of motion'."""
        a = np.asarray(self.accel_even_mps2, float)
        if a.size == 0:
            return ""
        near, far = float(a[0]), float(a[-1])
        towards = "towards the lower plate" if near < 0 else "towards the upper plate"
        if self.exponential is not None:
            size = (f"force {100 * abs(self.exponential['accel_at_contact_mps2']) / G_MPS2:.0f} % of the weight "
                    f"{towards} at contact, decaying with the distance from the lower plate (over "
                    f"{self.exponential['decay_mm']:.1f} mm)")
        else:
            trend = ("decaying with the distance from the lower plate" if abs(near) > abs(far)
                     else "growing with the distance from the lower plate")
            size = (f"force {100 * abs(near) / G_MPS2:.0f} % of the weight {towards} near the lower plate, "
                    f"{100 * abs(far) / G_MPS2:.0f} % near the upper plate, {trend}")
        dirn = ("and a part that changes sign with the direction of motion" if self.direction_dependent
                else "independent of the direction of motion")
        terms = " + ".join(self.model_terms) or "gravity alone"
        return (f"the flights' residual after {terms} depends on the ball's position in the cavity: {size}, "
                f"{dirn}")


def _relative_histories(meas: Measured, flights: FlightModelFit, motion: StructureKinematics
                        ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per flight (u, ball - structure (m), ball velocity (m/s)) on the model's integration grid."""
    out = []
    for k, fl in enumerate(meas.flights):
        u, v = flights.grids[k]
        y = flights.y0[k] + _cumtrapz(v, u[1] - u[0])
        out.append((u, y - np.asarray(motion.position(fl.t_ref_s + u), float), v))
    return out


def _lower_level(meas: Measured, flights: FlightModelFit, motion: StructureKinematics, hist) -> float:
    """Ball - structure at the lower plate: the median at the bottom impacts (model flights at the impact
    times), else the lowest point of every flight's history."""
    vals = []
    for imp in meas.impacts:
        k = imp.flight_after if imp.flight_after is not None else imp.flight_before
        if imp.plate != "bottom" or k is None:
            continue
        y, _ = flights.state(k, imp.t_s - meas.flights[k].t_ref_s)
        vals.append(float(y) - float(motion.position(imp.t_s)))
    if vals:
        return float(np.median(vals))
    return float(min(np.min(r) for _, r, _ in hist))


def _columns(meas: Measured, flights: FlightModelFit, hist, accel_fns) -> np.ndarray:
    """The projected design (rows: every fitted frame) of extra accelerations ``accel_fns`` (each
    f(rel, v) -> m/s^2 on a grid), double-integrated along each flight and with [1, tau] projected out."""
    blocks = []
    for k, fl in enumerate(meas.flights):
        u, rel, v = hist[k]
        du = u[1] - u[0]
        tau = fl.tau_s
        cols = [np.interp(tau, u, _cumtrapz(_cumtrapz(f(rel, v), du), du)) for f in accel_fns]
        X = np.column_stack(cols) if cols else np.zeros((tau.size, 0))
        L = np.column_stack([np.ones_like(tau), tau])
        Q, _ = np.linalg.qr(L)
        blocks.append(X - Q @ (Q.T @ X))
    return np.vstack(blocks)


def _target(meas: Measured, g: float) -> np.ndarray:
    """The ball positions plus gravity's fall, [1, tau] projected out per flight."""
    out = []
    for fl in meas.flights:
        tau = fl.tau_s
        r = fl.y_m + 0.5 * g * tau ** 2
        L = np.column_stack([np.ones_like(tau), tau])
        Q, _ = np.linalg.qr(L)
        out.append(r - Q @ (Q.T @ r))
    return np.concatenate(out)


def column_rank(X: np.ndarray) -> int:
    """Rank of ``X`` with its columns scaled to unit norm (terms of very different units compare fairly)."""
    if X.shape[1] == 0:
        return 0
    scale = np.sqrt(np.sum(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    return int(np.linalg.matrix_rank(X / scale, tol=1e-9))


def ols_fit(X: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Ordinary least squares of ``r`` on the columns of ``X`` (solved with the columns scaled): coefficients,
    sum of squared residuals, (X^T X)^-1 (NaN when singular)."""
    if X.shape[1] == 0:
        return np.zeros(0), float(r @ r), np.zeros((0, 0))
    scale = np.sqrt(np.sum(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    c, *_ = np.linalg.lstsq(X / scale, r, rcond=None)
    c = c / scale
    res = r - X @ c
    try:
        inv = np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        inv = np.full((X.shape[1], X.shape[1]), np.nan)
    return c, float(res @ res), inv


def position_bins(lower_m: float, hist) -> tuple[np.ndarray, list, list]:
    """``N_BINS`` equal bins of the ball's height above the lower contact level ``lower_m`` (m) up to the highest
    point of the histories ``hist`` ((t, rel, v) per flight): the bin edges (m) and, per bin, an indicator
    function of (rel, v) (the first and last bins open-ended) and the same times the sign of v (the part that
    changes sign with the direction of motion)."""
    span = max(float(max(np.max(r) for _, r, _ in hist)) - lower_m, 1e-6)
    edges = lower_m + span * np.linspace(0.0, 1.0, N_BINS + 1)

    def in_bin(j):
        lo, hi = edges[j], edges[j + 1]
        if j == 0:
            return lambda rel, v: (rel < hi).astype(float)
        if j == N_BINS - 1:
            return lambda rel, v: (rel >= lo).astype(float)
        return lambda rel, v: ((rel >= lo) & (rel < hi)).astype(float)

    def odd(f):
        return lambda rel, v: f(rel, v) * np.sign(v)

    even = [in_bin(j) for j in range(N_BINS)]
    return edges, even, [odd(f) for f in even]


def check_flight_shape(meas: Measured, flights: FlightModelFit, motion: StructureKinematics,
                       sigma_m: float) -> ShapeCheck | None:
    """The shape test of the module docstring for the fitted flight model ``flights`` (its terms and
    velocity histories) around the structure ``motion``; ``sigma_m`` the ball's noise floor per frame.
    None when there are too few flights or no integration grids."""
    if len(meas.flights) < 3 or not flights.grids or not sigma_m > 0:
        return None
    g, m = flights.g_mps2, meas.mass_kg
    hist = _relative_histories(meas, flights, motion)
    lower = _lower_level(meas, flights, motion, hist)
    edges, even_fns, odd_fns = position_bins(lower, hist)
    term_fns = [(lambda t: (lambda rel, v: t.basis(v, m)))(t) for t in flights.terms]
    r = _target(meas, g)
    n = r.size
    sig2 = sigma_m ** 2
    X_t = _columns(meas, flights, hist, term_fns)
    X_e = _columns(meas, flights, hist, even_fns)
    X_o = _columns(meas, flights, hist, odd_fns)
    _, sse_t, _ = ols_fit(X_t, r)
    tests = {}
    structured = False
    for name, X in (("position", X_e), ("position_x_direction", X_o)):
        _, sse, _ = ols_fit(np.hstack([X_t, X]), r)
        chi = (sse_t - sse) / sig2
        dof = column_rank(np.hstack([X_t, X])) - column_rank(X_t)  # a term the bins span counts once
        p = chi2_sf(max(chi, 0.0), max(dof, 1))
        ex = math.sqrt(max(sse_t - sse, 0.0) / max(n, 1)) / sigma_m
        ok = p < ALPHA and ex >= MIN_EXPLAINED_SIGMA
        structured |= ok
        tests[name] = {"chi2": chi, "dof": dof, "p_value": p, "explained_x_noise": ex, "structured": ok}
    # the shape itself, free of the catalogue: even and odd bins together
    c, sse_eo, inv = ols_fit(np.hstack([X_e, X_o]), r)
    s2 = sse_eo / max(n - 2 * len(meas.flights) - c.size, 1)
    even, odd_c = c[:N_BINS], c[N_BINS:]
    even_sd = np.sqrt(np.clip(np.diag(inv)[:N_BINS] * s2, 0, None)) if inv.size else np.zeros(N_BINS)
    _, sse_e_only, _ = ols_fit(X_e, r)
    chi_odd = (sse_e_only - sse_eo) / sig2
    ex_odd = math.sqrt(max(sse_e_only - sse_eo, 0.0) / max(n, 1)) / sigma_m
    direction_dependent = chi2_sf(max(chi_odd, 0.0), N_BINS) < ALPHA and ex_odd >= MIN_EXPLAINED_SIGMA
    tests["direction_part"] = {"chi2": chi_odd, "explained_x_noise": ex_odd, "significant": direction_dependent}
    expo = None
    r0 = float(r @ r)
    best = None
    for L_mm in DECAYS_MM if structured else ():
        L = 1e-3 * L_mm
        X = _columns(meas, flights, hist, [lambda rel, v, L=L: np.exp(-np.clip(rel - lower, 0, None) / L)])
        cc, sse, inv1 = ols_fit(X, r)
        if best is None or sse < best[1]:
            sd = math.sqrt(max(float(inv1[0, 0]) * sse / max(n - 2 * len(meas.flights) - 1, 1), 0.0))
            best = (L_mm, sse, float(cc[0]), sd)
    if best is not None and r0 - sse_e_only > 0 and (r0 - best[1]) >= EXP_SHARE * (r0 - sse_e_only) \
            and DECAYS_MM[0] < best[0] < DECAYS_MM[-1]:
        expo = {"accel_at_contact_mps2": best[2], "accel_at_contact_std_mps2": best[3], "decay_mm": best[0],
                "decay_grid_ratio": DECAYS_MM[1] / DECAYS_MM[0],
                "explained_share_of_bins": (r0 - best[1]) / (r0 - sse_e_only)}
    return ShapeCheck(structured=structured, model_terms=tuple(flights.names), tests=tests,
                      bin_edges_mm=[float(x) for x in 1e3 * (edges - lower)], accel_even_mps2=[float(x) for x in even],
                      accel_even_std_mps2=[float(x) for x in even_sd], accel_odd_mps2=[float(x) for x in odd_c],
                      direction_dependent=bool(direction_dependent), exponential=expo, g_mps2=g)
