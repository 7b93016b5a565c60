"""Is the mismatch the lens? The signature of an uncalibrated camera (issue 40).

A lens that is not a pinhole maps the true position Y to an apparent one Y + delta(Y): the image scale changes
across the image (a barrel lens of an ordinary machine-vision camera: ~1.5 % between the image centre and the
plates). Near a point Yc, delta(Y) = 1/2 kappa (Y - Yc)^2 + ... (kappa: the scale's relative gradient, 1/m). It
shows twice: the plate's apparent sine gains a 2nd harmonic in cosine phase (1/4 kappa A^2 cos 2 theta), and
every flight's apparent path bends by a function of the ball's position alone, which the analysis, comparing
with gravity, reads as a force that depends on where the ball is. Neither is physics; the remedy is a camera
calibration (``vibro calibrate``, or ROS camera_calibration) named in rig.yaml ``camera.calibration``.

The test (:func:`lens_check`), for a rig without a calibration: the flights' residual against gravity (each
flight's state free, gravity free for a scale or tilt) is regressed on the static position columns
(Y - Ybar)^2 and (Y - Ybar)^3 along each flight's fitted path. A lens leaves the noise
(residual <= :data:`NOISE_RATIO` noise floors after, from more than that before, where the catalogue's flight
terms leave the flights unexplained); a force does not, because its
effect on a flight is the double integral of the force along the path, not a function of the position alone
(measured: a position force of 25 % of the weight leaves 2.7 noise floors, a drag 13, a Coulomb friction 11; a
barrel lens k1 = -0.18 leaves 0.99). Where the signature holds, the findings are reported as a probable optical
effect with the remedy, not claimed as physics (:func:`lens_findings`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from vibro_discrepancy.data import Measured, difference_sigma
from vibro_model.codec import json_number
from vibro_model.results import DiscrepancyFinding

#: a residual within this many noise floors is noise (the analysis' own unexplained ratio)
NOISE_RATIO = 1.5
#: fewer flights: no lens test
MIN_FLIGHTS = 5
#: the effect name the findings take when the lens explains them (the contract's name for what no modelled
#: physics accounts for)
UNEXPLAINED = "unexplained"
REMEDY = ("calibrate the camera (vibro calibrate IMAGES --pattern COLSxROWS --square-mm S, or ROS "
          "camera_calibration) and name its camera_info.yaml in rig.yaml camera.calibration")


@dataclass(frozen=True)
class LensCheck:
    """The flights' residual against gravity before and after the static position columns, in noise floors, and
    the scale gradient kappa (1/m) they give; ``signature``: a lens explains the flights (module docstring)."""

    before_x_noise: float
    after_x_noise: float
    kappa_per_m: float
    kappa_std_per_m: float
    signature: bool

    def words(self) -> str:
        return (f"probably the camera's lens, not physics: the flights' residual is a function of the ball's "
                f"position in the image alone, as a lens that is not a pinhole makes it (a scale changing by "
                f"{100 * self.kappa_per_m * 1e-3:+.2g} % per mm across the image: the residual falls from "
                f"{self.before_x_noise:.1f} to {self.after_x_noise:.1f} noise floors), and rig.yaml names no camera "
                f"calibration; {REMEDY}")

    def to_dict(self) -> dict[str, Any]:
        return {"signature": self.signature, "residual_before_x_noise": json_number(self.before_x_noise),
                "residual_after_x_noise": json_number(self.after_x_noise),
                "scale_gradient_per_m": json_number(self.kappa_per_m),
                "scale_gradient_std_per_m": json_number(self.kappa_std_per_m), "remedy": REMEDY}


def _columns(meas: Measured) -> tuple[np.ndarray, np.ndarray]:
    """(residual against gravity, [tau^2, (Y - Ybar)^2, (Y - Ybar)^3]) over every flight's frames, each flight's
    [1, tau] projected out (its state free); Y the flight's fitted path under gravity."""
    g = meas.g_mps2
    ybar = float(np.mean(np.concatenate([f.y_m for f in meas.flights])))
    rows, cols = [], []
    for f in meas.flights:
        tau = f.tau_s
        r = f.y_m + 0.5 * g * tau ** 2
        L = np.column_stack([np.ones_like(tau), tau])
        Q, _ = np.linalg.qr(L)
        c, *_ = np.linalg.lstsq(L, r, rcond=None)
        d = L @ c - 0.5 * g * tau ** 2 - ybar
        X = np.column_stack([tau ** 2, d ** 2, d ** 3])
        rows.append(r - Q @ (Q.T @ r))
        cols.append(X - Q @ (Q.T @ X))
    return np.concatenate(rows), np.vstack(cols)


def lens_check(meas: Measured, catalogue_x_noise: float = math.inf) -> LensCheck | None:
    """The lens test (module docstring) of ``meas``; None for a calibrated camera, too few flights or no noise
    floor. ``catalogue_x_noise``: what the catalogue's chosen flight model leaves of the flights, in noise floors
    (the selection's flight stage): a lens is named only where the catalogue leaves the flights unexplained and the
    position columns explain them (a small Coulomb friction, which a quadratic in position also follows, is the
    catalogue's)."""
    if meas.calibrated or len(meas.flights) < MIN_FLIGHTS:
        return None
    noise = difference_sigma([(f.t_s, f.y_m) for f in meas.flights], 3)
    if not (math.isfinite(noise) and noise > 0):
        return None
    r, X = _columns(meas)
    n = r.size
    base_coef, *_ = np.linalg.lstsq(X[:, :1], r, rcond=None)
    base = r - X[:, :1] @ base_coef
    coef, *_ = np.linalg.lstsq(X, r, rcond=None)
    after = r - X @ coef
    s2 = float(after @ after) / max(n - X.shape[1], 1)
    try:
        kappa_var = 4.0 * s2 * float(np.linalg.inv(X.T @ X)[1, 1])
    except np.linalg.LinAlgError:
        return None
    before_x = math.sqrt(float(base @ base) / n) / noise
    after_x = math.sqrt(float(after @ after) / n) / noise
    kappa = 2.0 * float(coef[1])
    return LensCheck(before_x_noise=before_x, after_x_noise=after_x, kappa_per_m=kappa,
                     kappa_std_per_m=math.sqrt(max(kappa_var, 0.0)),
                     signature=before_x > NOISE_RATIO and after_x <= NOISE_RATIO
                     and catalogue_x_noise > NOISE_RATIO)


def lens_findings(findings: Sequence[DiscrepancyFinding], check: LensCheck | None) -> list[DiscrepancyFinding]:
    """``findings`` as reported when the lens signature holds: one ``unexplained`` finding that names the probable
    optical effect and the remedy, saying what the mismatch would otherwise have been taken for (each finding's
    effect and words); the findings unchanged otherwise."""
    if check is None or not check.signature or not findings:
        return list(findings)
    taken = [f for f in findings if f.effect != UNEXPLAINED]
    first = findings[0]
    where = check.words()
    if taken:
        where += "; not claimed: " + "; ".join(f"{f.effect} ({f.where})" for f in taken)
    rest = [f.where for f in findings if f.effect == UNEXPLAINED]
    if rest:
        where += "; what is left: " + "; ".join(rest)
    return [DiscrepancyFinding(effect=UNEXPLAINED, parameters={}, where=where,
                               deviation_before=first.deviation_before,
                               deviation_after=findings[-1].deviation_after,
                               details={"probable_cause": "lens_distortion", "lens": check.to_dict(),
                                        "not_claimed": [f.effect for f in taken]})]
