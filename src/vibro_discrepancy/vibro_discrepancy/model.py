"""A fitted model of the recording: structure motion + flight law + COR law (and their fits).

The baseline is structure orders (1,), no flight term (gravity only, vertical) and the constant COR
law ("none") equal to the mean measured COR. Candidate models add terms from the library.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import (
    CorModelFit,
    FlightModelFit,
    ImpactSet,
    StructureModelFit,
    fit_cor,
    fit_flights,
    fit_structure_harmonics,
    recompute_impacts,
)
from vibro_discrepancy.library import (
    AsymmetricRestitution,
    ConstantRestitution,
    FlightTerm,
    PlateAndSpeed,
    VelocityDependentRestitution,
    cor_values,
    force_law,
    restitution_law,
    total_tilt_deg,
    vertical_gravity_mps2,
)
from vibro_model.drive_envelope import DriveEnvelope, under_envelope
from vibro_model.kinematics import StructureKinematics
from vibro_sim.params import BallCavity
from vibro_sim.plates import MovedPlate

COR_TERMS = {"none": ConstantRestitution(), "asymmetric_restitution": AsymmetricRestitution(),
             "velocity_dependent_restitution": VelocityDependentRestitution(), "plate_and_speed": PlateAndSpeed()}


@dataclass(kw_only=True)
class FittedModel:
    """Structure, flights and COR fitted together (SI, DIC frame)."""

    structure: StructureModelFit
    flights: FlightModelFit
    impacts: ImpactSet
    cor: CorModelFit
    g_mps2: float
    fixed_motion: StructureKinematics | None = None   # a known structure motion (the true model in proofs)
    axis_tilt_deg: float = 0.0    # rig.yaml setup.axis_tilt_deg: the axis' declared tilt (g_mps2 its gravity)
    with_plates: bool = False     # replayed with the plates' measured motion (Measured.plate_creeps)
    #: the drive as it moved over the take (Measured.drive_envelope): the fitted structure under it; None: the
    #: drive held still and the fitted structure is the motion
    envelope: DriveEnvelope | None = None

    @property
    def motion(self) -> StructureKinematics:
        if self.fixed_motion is not None:
            return self.fixed_motion
        return under_envelope(self.structure.motion(), self.envelope)

    @property
    def tilt_deg(self) -> float:
        """The axis' total tilt from vertical (deg): the declared one (``axis_tilt_deg``, ``g_mps2`` its gravity)
        with the gravity_tilt term's change c, acos(cos theta - c / g)
        (:func:`~vibro_discrepancy.library.total_tilt_deg`)."""
        return total_tilt_deg(self.flights.coef_of("gravity_tilt"), self.g_mps2, self.axis_tilt_deg)

    def accel(self, v_mps: np.ndarray, mass_kg: float) -> np.ndarray:
        """Free-flight acceleration (m/s^2) at ball velocity v (lab frame)."""
        v = np.asarray(v_mps, dtype=float)
        out = np.full_like(v, -self.g_mps2)
        for t, c in zip(self.flights.terms, self.flights.coefs):
            if c != 0.0:
                out = out + c * t.basis(v, mass_kg)
        return out

    #: the flight force depends on the ball's position (and time), not on its velocity alone: a one-step
    #: integration must call :meth:`flight_accel`
    state_dependent = False

    def flight_accel(self, t_s, y_m, v_mps, mass_kg: float) -> np.ndarray:
        """Free-flight acceleration (m/s^2) at camera time ``t_s``, ball position ``y_m`` (DIC frame) and
        velocity ``v_mps``; here the velocity law :meth:`accel` (a shape model adds a position force)."""
        return self.accel(v_mps, mass_kg)

    def cor_at(self, plates, speeds_mps, index=None) -> np.ndarray:
        """COR of the law at each (plate, |v_rel|); ``index`` (the impacts' indices into
        :attr:`Measured.impacts`) matters only to a law of the impact count (a parity shape model)."""
        return cor_values(self.cor.kind, self.cor.coefs, plates, speeds_mps)

    def force_law(self):
        return force_law(self.flights.coef_dict())

    def restitution_law(self):
        return restitution_law(self.cor.kind, self.cor.coefs)

    def cavity(self, meas: Measured, free_play_m: float) -> BallCavity:
        # g and the total tilt: g cos(tilt) is the declared axis' gravity with the tilt term's change
        return BallCavity(mass_kg=meas.mass_kg, free_play_m=free_play_m,
                          gravity_mps2=vertical_gravity_mps2(self.g_mps2, self.axis_tilt_deg), tilt_deg=self.tilt_deg)

    def label(self) -> str:
        parts = self.structure.label_terms()
        parts += [t.effect for t, c in zip(self.flights.terms, self.flights.coefs)]
        if self.cor.kind != "none":
            parts.append(self.cor.kind)
        if self.with_plates:
            parts.append("plate_motion")
        return " + ".join(parts) or "baseline"


def fit_model(meas: Measured, orders=(1,), flight_terms: tuple[FlightTerm, ...] = (), cor_kind: str = "none",
              structure: StructureModelFit | None = None, flights: FlightModelFit | None = None) -> FittedModel:
    """Fit a whole model; ``structure``/``flights`` reuse fits already made."""
    s = structure if structure is not None else fit_structure_harmonics(meas.t_s, meas.structure_m, meas.frequency_hz,
                                                              orders)
    f = flights if flights is not None else fit_flights(meas, flight_terms)
    envelope = meas.drive_envelope
    imp = recompute_impacts(meas, f, under_envelope(s.motion(), envelope))
    c = fit_cor(imp, COR_TERMS[cor_kind], cor_kind)
    return FittedModel(structure=s, flights=f, impacts=imp, cor=c, g_mps2=meas.g_mps2,
                       axis_tilt_deg=meas.axis_tilt_deg, envelope=envelope)


def model_plate_levels(meas: Measured, model: FittedModel) -> dict[str, float]:
    """Relative position ball - structure (m, DIC frame) of each plate at the impacts under ``model``
    (median), the cavity offset c0 = ball centre - cavity centre at frame 0 in the DIC frame, and the
    measured free play b (half the relative travel). One plate only: b from the rig."""
    S = model.motion
    vals: dict[str, list[float]] = {"top": [], "bottom": []}
    imps = model.impacts
    for i, t, plate in zip(imps.index, imps.t_s, imps.plate):
        imp = meas.impacts[int(i)]
        k = imp.flight_before if imp.flight_before is not None else imp.flight_after
        if k is None:
            continue
        y, _ = model.flights.state(k, t - meas.flights[k].t_ref_s)
        vals[plate].append(float(y) - float(S.position(t)))
    out = {p: float(np.median(v)) for p, v in vals.items() if v}
    b_rig = meas.free_play_m
    if "top" in out and "bottom" in out:
        out["offset"] = -0.5 * (out["top"] + out["bottom"])
        out["free_play"] = 0.5 * (out["top"] - out["bottom"])
    elif "top" in out:
        out["offset"], out["free_play"] = b_rig - out["top"], b_rig
    elif "bottom" in out:
        out["offset"], out["free_play"] = -b_rig - out["bottom"], b_rig
    else:
        out["offset"], out["free_play"] = 0.0, b_rig
    return out


def moved_plates(meas: Measured, model: FittedModel) -> dict:
    """The plates that creep (the identification's ``plate_motion``, :attr:`Measured.plate_creeps`) as the
    simulator reads them around ``model``'s structure, when the model is replayed with them (``with_plates``);
    else {}. Each plate's creep is taken about its median over the plate's impacts, where
    :func:`model_plate_levels` puts the plate (m; derivative bounds over the recording +- 1 s)."""
    if not model.with_plates or not meas.plate_creeps:
        return {}
    span = (float(meas.t_s[0]) - 1.0, float(meas.t_s[-1]) + 1.0)
    out = {}
    for plate, creep in meas.plate_creeps.items():
        times = [float(t) for t, p in zip(model.impacts.t_s, model.impacts.plate) if p == plate]
        coef = 1e-6 * np.asarray(creep.coef_um, dtype=float)
        if times:
            coef[-1] -= float(np.median(np.polyval(coef, np.asarray(times) - creep.t_ref_s)))
        out[plate] = MovedPlate(model.motion, tuple(float(c) for c in coef), creep.t_ref_s, span)
    return out
