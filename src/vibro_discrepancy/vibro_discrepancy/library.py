"""Candidate physics terms: what the baseline model (constant COR, gravity only, pure sine structure,
vertical axis) may have left out. One small class per contract effect name.

Each term states its parameters (SI, contract names), its signature (how it shows in the data) and
what it modifies: the flight force law, the effective gravity, the COR law or the structure motion.

Flight terms add an acceleration ``coef * basis(v)`` (m/s^2, v = ball velocity in the lab frame, m/s,
positive up) to the ball's free flight y'' = -g_axis + ...; g_axis = g cos(theta) is the gravity along the
axis as declared (rig.yaml ``setup.axis_tilt_deg`` theta, 0 when vertical). The coefficient is in the term's own
SI unit (force terms: N, N s/m, N s^2/m^2, divided by the ball mass in ``basis``; tilt: the upward change of
acceleration c = g (cos theta - cos theta_total) in m/s^2, an UNDECLARED tilt beyond the declared one; its
contract parameter ``tilt_deg`` is the total tilt from vertical, theta_total = acos(cos theta - c / g), g the
nominal 9.81). Impact terms are linear COR laws e = X(plate, speed) @ coefs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vibro_model.constants import G_MPS2
from vibro_sim.forces import Coulomb, ForceLaw, NoForce, Quadratic, Viscous
from vibro_sim.restitution import PLATES, Constant, PerPlate, RestitutionLaw, VelocityDependent

# --- physical floors (docs/method.md, "Physical floors") ------------------------------------------
# A term's significance grows with the length of the recording (its chi^2 with the number of frames), so a
# long take makes ever smaller effects significant, down to the DIC's own systematic errors. A term is a
# finding only when it is also larger than its floor: what it changes must matter for the COR (~1e-3) and be
# above what the DIC resolves. The floors are in the units the terms act in:

#: flight terms (Coulomb friction, viscous and quadratic drag, gravity tilt): the term's force at the fastest
#: flight speed measured, as a fraction of the ball's weight m g (tilt: m g (1 - cos tilt)). A force F changes
#: the ball's speed over a flight of duration T by F T / m against a flight speed of order g T / 2: ~2 F / (m g)
#: relative, so 1e-3 m g shifts a predicted COR by ~1e-3; one 20-frame flight's fitted acceleration resolves
#: 4e-4 to 1.5e-3 m g at 0.25-1 um of DIC noise per frame; the same floor as vibro_fit.plausibility's
#: FRICTION_FLOOR_OF_WEIGHT (the cross-check that refuses a friction feeding energy in)
FORCE_FLOOR_OF_WEIGHT = 1e-3
#: the COR change below which a term does not matter: structure harmonics (the plate velocity error
#: k h_k A 2 pi f at impact, as a COR change (1 + e) k h_k A 2 pi f / |v_rel|), COR laws (the change of the
#: predicted COR over the measured impacts, their speeds and plates); the COR floor of the cross-checks
#: (vibro_fit.plausibility.COR_FLOOR) and of the order the force floor maps to
COR_EFFECT_FLOOR = 1e-3

EFFECTS = ("coulomb_friction", "viscous_drag", "quadratic_drag", "asymmetric_restitution",
           "velocity_dependent_restitution", "gravity_tilt", "structure_harmonics")
UNEXPLAINED = "unexplained"


class Term:
    """A candidate physics term. ``effect`` is the contract name."""

    effect: str = ""
    stage: str = ""          # "structure", "flight" or "impact"
    modifies: str = ""       # plain words
    parameters: tuple[str, ...] = ()
    signature: str = ""

    def describe(self) -> dict:
        return {"effect": self.effect, "stage": self.stage, "modifies": self.modifies,
                "parameters": list(self.parameters), "signature": self.signature}


# --- flight terms ------------------------------------------------------------------------------

class FlightTerm(Term):
    stage = "flight"
    unit = ""

    def basis(self, v_mps: np.ndarray, mass_kg: float) -> np.ndarray:
        """Acceleration (m/s^2) per unit coefficient at ball velocity ``v_mps``."""
        raise NotImplementedError

    def contract_parameters(self, coef: float, std: float, mass_kg: float, g_mps2: float,
                            axis_tilt_deg: float = 0.0) -> tuple[dict, dict]:
        """(parameters, their 1-sigma std) in contract names (``g_mps2``: the gravity along the axis the flights
        were fitted with; ``axis_tilt_deg``: the axis' declared tilt, rig.yaml setup.axis_tilt_deg)."""
        name = self.parameters[0]
        return {name: float(coef)}, {name: float(std)}

    def peak_force_n(self, coef: float, speed_mps: float, mass_kg: float) -> float:
        """|force| (N) of the term with coefficient ``coef`` at the speed ``speed_mps`` (Coulomb and tilt: at
        any speed; the drags grow with it): ``mass_kg`` |coef basis(speed)|."""
        return float(mass_kg * abs(coef * self.basis(np.array([abs(speed_mps)]), mass_kg)[0]))

    def negligible(self, coef: float, speed_mps: float, mass_kg: float, g_mps2: float = G_MPS2) -> bool:
        """True when the term's force at the fastest measured speed ``speed_mps`` is below the physical floor
        :data:`FORCE_FLOOR_OF_WEIGHT` m g (``g_mps2``: g, the ball's weight, whatever the axis' orientation): not
        a finding, however significant."""
        return self.peak_force_n(coef, speed_mps, mass_kg) < FORCE_FLOOR_OF_WEIGHT * mass_kg * g_mps2

    def lower_bound(self, g_axis_mps2: float, axis_tilt_deg: float = 0.0) -> float:
        """The least coefficient this physics can have (term units) when the flights are fitted with gravity
        ``g_axis_mps2`` along an axis declared ``axis_tilt_deg`` from vertical: 0 (a force that speeds the ball up
        is not this physics; a tilt: see :class:`GravityTilt`)."""
        return 0.0


class CoulombFriction(FlightTerm):
    effect = "coulomb_friction"
    modifies = "flight force law"
    parameters = ("force_n",)
    unit = "N"
    signature = ("constant deceleration along the motion: the ball loses more speed rising and gains less "
                 "falling than gravity alone; the extra acceleration flips sign with the direction of motion "
                 "and does not depend on the speed")

    def basis(self, v_mps, mass_kg):
        return -np.sign(v_mps) / mass_kg


class ViscousDrag(FlightTerm):
    effect = "viscous_drag"
    modifies = "flight force law"
    parameters = ("coefficient_ns_per_m",)
    unit = "N s/m"
    signature = "extra deceleration proportional to the speed: grows linearly from the apex to the fast ends"

    def basis(self, v_mps, mass_kg):
        return -np.asarray(v_mps, dtype=float) / mass_kg


class QuadraticDrag(FlightTerm):
    effect = "quadratic_drag"
    modifies = "flight force law"
    parameters = ("coefficient_ns2_per_m2",)
    unit = "N s^2/m^2"
    signature = "extra deceleration proportional to the speed squared: negligible near the apex, largest fast"

    def basis(self, v_mps, mass_kg):
        v = np.asarray(v_mps, dtype=float)
        return -v * np.abs(v) / mass_kg


class GravityTilt(FlightTerm):
    effect = "gravity_tilt"
    modifies = "effective gravity"
    parameters = ("tilt_deg",)
    unit = "m/s^2"
    signature = ("every flight accelerates along the axis by the same amount more or less than the declared "
                 "gravity g cos(setup.axis_tilt_deg), whatever its direction or speed (an undeclared tilt: "
                 "effective gravity g cos(tilt))")

    def basis(self, v_mps, mass_kg):
        return np.ones_like(np.asarray(v_mps, dtype=float))

    def lower_bound(self, g_axis_mps2: float, axis_tilt_deg: float = 0.0) -> float:
        """A tilt cannot make gravity along the axis exceed g: c >= g_axis - g (0 on an axis declared vertical; on
        one declared tilted the true tilt may be smaller than declared, c < 0; on a horizontal one the constant
        is a force along the axis either way, the axis tilted short of or beyond horizontal). g here is the one
        the flights' gravity was scaled with (:func:`vertical_gravity_mps2`)."""
        return min(float(g_axis_mps2) - vertical_gravity_mps2(g_axis_mps2, axis_tilt_deg), 0.0)

    def contract_parameters(self, coef, std, mass_kg, g_mps2, axis_tilt_deg=0.0):
        """``tilt_deg``: the axis' TOTAL tilt from vertical, theta_total = acos(cos theta - c / g) with theta the
        declared tilt (rig.yaml setup.axis_tilt_deg), c the fitted coefficient and g the nominal 9.81
        (:func:`total_tilt_deg`); its std d theta / d c = 1 / (g sin theta_total) (deg)."""
        tilt = total_tilt_deg(coef, g_mps2, axis_tilt_deg)
        s = math.sin(math.radians(tilt))
        g = vertical_gravity_mps2(g_mps2, axis_tilt_deg)
        std_deg = math.degrees(std / (g * s)) if s > 1e-9 else float("inf")
        return {"tilt_deg": tilt}, {"tilt_deg": std_deg}


def vertical_gravity_mps2(g_axis_mps2: float, axis_tilt_deg: float = 0.0) -> float:
    """The full gravity g that the gravity ``g_axis_mps2`` along an axis declared ``axis_tilt_deg`` from vertical is
    the axial part of: g_axis / cos(theta); the nominal :data:`~vibro_model.constants.G_MPS2` on an axis within 3
    deg of horizontal. It is g itself, unless the image scale's uncertainty scaled the flights' gravity
    (:mod:`.instrument_scale`): then g by the same factor."""
    c = math.cos(math.radians(float(axis_tilt_deg)))
    return float(g_axis_mps2) / c if c > 0.05 else G_MPS2


def total_tilt_deg(coef_mps2: float, g_axis_mps2: float, axis_tilt_deg: float = 0.0) -> float:
    """The axis' total tilt from vertical (deg, 0..180) when the flights fall at g_axis - c along it:
    theta_total = acos((g_axis - c) / g) = acos(cos theta - c / g), ``g_axis_mps2`` = g cos(theta) the gravity
    along the axis declared ``axis_tilt_deg`` = theta from vertical, ``coef_mps2`` = c the gravity_tilt
    coefficient (up), g = :func:`vertical_gravity_mps2` (the nominal 9.81)."""
    g = vertical_gravity_mps2(g_axis_mps2, axis_tilt_deg)
    x = min(max((float(g_axis_mps2) - float(coef_mps2)) / g, -1.0), 1.0)
    return math.degrees(math.acos(x))


FLIGHT_TERMS: tuple[FlightTerm, ...] = (CoulombFriction(), ViscousDrag(), QuadraticDrag(), GravityTilt())


# --- impact (COR) terms ------------------------------------------------------------------------

class ImpactTerm(Term):
    stage = "impact"
    modifies = "COR law"

    def columns(self, plates: np.ndarray, speeds_mps: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def contract_parameters(self, coefs: np.ndarray, cov: np.ndarray) -> tuple[dict, dict]:
        raise NotImplementedError


class ConstantRestitution(ImpactTerm):
    """The baseline COR law: one value for every impact."""

    effect = "none"
    parameters = ("cor",)

    def columns(self, plates, speeds_mps):
        return np.ones((len(plates), 1))

    def contract_parameters(self, coefs, cov):
        return {"cor": float(coefs[0])}, {"cor": float(math.sqrt(cov[0, 0]))}


class AsymmetricRestitution(ImpactTerm):
    effect = "asymmetric_restitution"
    parameters = ("cor_top", "cor_bottom")
    signature = ("the CORs of the two plates differ whatever the impact speed; within one plate the COR does not "
                 "follow the impact speed")

    def columns(self, plates, speeds_mps):
        p = np.asarray(plates)
        return np.column_stack([(p == "top").astype(float), (p == "bottom").astype(float)])

    def contract_parameters(self, coefs, cov):
        return ({"cor_top": float(coefs[0]), "cor_bottom": float(coefs[1])},
                {"cor_top": float(math.sqrt(cov[0, 0])), "cor_bottom": float(math.sqrt(cov[1, 1]))})


class VelocityDependentRestitution(ImpactTerm):
    effect = "velocity_dependent_restitution"
    parameters = ("cor_at_zero", "slope_s_per_m")
    signature = ("the COR falls with the relative impact speed on both plates alike (e = e0 - slope |v_rel|), "
                 "also within one plate when the speeds vary")

    def columns(self, plates, speeds_mps):
        s = np.asarray(speeds_mps, dtype=float)
        return np.column_stack([np.ones_like(s), -s])

    def contract_parameters(self, coefs, cov):
        return ({"cor_at_zero": float(coefs[0]), "slope_s_per_m": float(coefs[1])},
                {"cor_at_zero": float(math.sqrt(cov[0, 0])), "slope_s_per_m": float(math.sqrt(cov[1, 1]))})


class PlateAndSpeed(ImpactTerm):
    """Both: e = e_plate - slope |v_rel| (used to test for a within-plate speed dependence)."""

    effect = "asymmetric_restitution+velocity_dependent_restitution"
    parameters = ("cor_top", "cor_bottom", "slope_s_per_m")

    def columns(self, plates, speeds_mps):
        return np.column_stack([AsymmetricRestitution().columns(plates, speeds_mps), -np.asarray(speeds_mps, float)])

    def contract_parameters(self, coefs, cov):
        names = self.parameters
        return ({n: float(c) for n, c in zip(names, coefs)},
                {n: float(math.sqrt(cov[i, i])) for i, n in enumerate(names)})


IMPACT_TERMS: tuple[ImpactTerm, ...] = (AsymmetricRestitution(), VelocityDependentRestitution())



@dataclass(frozen=True)
class CandidateLibrary:
    """What the estimator may add to the baseline model, stage by stage (PySINDy's feature library):
    ``harmonics`` (structure_harmonics), the flight terms, the COR laws by contract name (a law outside
    ``cor_terms`` is never chosen). A narrower library makes an effect outside it come out unexplained."""

    flight_terms: tuple[FlightTerm, ...] = FLIGHT_TERMS
    cor_terms: tuple[str, ...] = tuple(t.effect for t in IMPACT_TERMS)
    harmonics: bool = True

    def impact_term(self, effect: str) -> "ImpactTerm":
        """The COR law named ``effect``."""
        return next(t for t in IMPACT_TERMS if t.effect == effect)

# --- structure term ------------------------------------------------------------------------------

class StructureHarmonics(Term):
    effect = "structure_harmonics"
    stage = "structure"
    modifies = "structure motion"
    parameters = ("h2_ratio", "h3_ratio")
    signature = ("the structure track departs from a pure sine periodically, at 2 and 3 times the shaker "
                 "frequency; impacts then meet the plates earlier or later than the sine says")
    orders = (2, 3)

    @staticmethod
    def cor_effect(order: int, ratio: float, drive_speed_mps: float, cor: float, impact_speed_mps: float) -> float:
        """The COR change a harmonic of ``order`` and amplitude ``ratio`` (to the fundamental) can make: its
        plate velocity ``order`` ratio A 2 pi f (``drive_speed_mps`` = A 2 pi f) at an impact of relative speed
        ``impact_speed_mps`` with COR ``cor``, (1 + e) dv / |v_rel| (Eq. 16 differentiated)."""
        if impact_speed_mps <= 0:
            return math.inf
        return (1.0 + cor) * order * abs(ratio) * drive_speed_mps / impact_speed_mps

    def negligible(self, order: int, ratio: float, drive_speed_mps: float, cor: float,
                   impact_speed_mps: float) -> bool:
        """True when the harmonic's COR change (:meth:`cor_effect`) is below :data:`COR_EFFECT_FLOOR`."""
        return self.cor_effect(order, ratio, drive_speed_mps, cor, impact_speed_mps) < COR_EFFECT_FLOOR


STRUCTURE_TERMS: tuple[StructureHarmonics, ...] = (StructureHarmonics(),)
ALL_TERMS: tuple[Term, ...] = STRUCTURE_TERMS + FLIGHT_TERMS + IMPACT_TERMS


def catalogue() -> list[dict]:
    """The candidate terms as plain mappings (effect, stage, modifies, parameters, signature)."""
    return [t.describe() for t in ALL_TERMS]


# --- the vibro_sim laws of a fitted model ---------------------------------------------------------

class SumForce(ForceLaw):
    """Sum of Coulomb, viscous and quadratic forces (N, positive up) and a constant upward force;
    integrated numerically by the COR model (kind "ode")."""

    kind = "ode"
    effect = "combined"

    def __init__(self, coulomb_n: float = 0.0, viscous_ns_per_m: float = 0.0, quadratic_ns2_per_m2: float = 0.0):
        self.coulomb_n = float(coulomb_n)
        self.viscous = float(viscous_ns_per_m)
        self.quadratic = float(quadratic_ns2_per_m2)

    def force_n(self, v_mps: float, flight_index: int = 0) -> float:
        s = 0.0 if v_mps == 0 else math.copysign(1.0, v_mps)
        return -self.coulomb_n * s - self.viscous * v_mps - self.quadratic * v_mps * abs(v_mps)


def force_law(flight_coefs: dict[str, float]) -> ForceLaw:
    """The vibro_sim force law for fitted flight-term coefficients (tilt excluded: it is in g_eff)."""
    f = {k: v for k, v in flight_coefs.items() if k != "gravity_tilt" and v != 0.0}
    if not f:
        return NoForce()
    if len(f) == 1:
        (name, value), = f.items()
        return {"coulomb_friction": Coulomb, "viscous_drag": Viscous, "quadratic_drag": Quadratic}[name](value)
    return SumForce(f.get("coulomb_friction", 0.0), f.get("viscous_drag", 0.0), f.get("quadratic_drag", 0.0))


class PlateSpeedLaw(RestitutionLaw):
    """e = e_plate - slope |v_rel|, clipped to [0, 1] (covers every linear COR law of the library)."""

    def __init__(self, top: float, bottom: float, slope_s_per_m: float = 0.0):
        self.top, self.bottom, self.slope = float(top), float(bottom), float(slope_s_per_m)

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        base = self.top if plate == "top" else self.bottom
        return float(min(1.0, max(0.0, base - self.slope * abs(v_rel_mps))))

    def __repr__(self) -> str:
        return f"PlateSpeedLaw(top={self.top:.4f}, bottom={self.bottom:.4f}, slope={self.slope:.4f})"


def restitution_law(kind: str, coefs) -> RestitutionLaw:
    """vibro_sim COR law for a fitted impact model: kind "none" ([e]), "asymmetric_restitution"
    ([top, bottom]), "velocity_dependent_restitution" ([e0, slope]) or "plate_and_speed"."""
    c = [float(x) for x in coefs]
    if kind == "none":
        return Constant(min(1.0, max(0.0, c[0])))
    if kind == "asymmetric_restitution":
        return PerPlate(min(1.0, max(0.0, c[0])), min(1.0, max(0.0, c[1])))
    if kind == "velocity_dependent_restitution":
        return VelocityDependent(min(1.0, max(0.0, c[0])), c[1])
    return PlateSpeedLaw(c[0], c[1], c[2])


def cor_values(kind: str, coefs, plates, speeds_mps) -> np.ndarray:
    """COR predicted by a fitted impact model for each (plate, |v_rel|)."""
    term = {"none": ConstantRestitution(), "asymmetric_restitution": AsymmetricRestitution(),
            "velocity_dependent_restitution": VelocityDependentRestitution(),
            "plate_and_speed": PlateAndSpeed()}[kind]
    return np.clip(term.columns(np.asarray(plates), np.asarray(speeds_mps, float)) @ np.asarray(coefs, float), 0, 1)


__all__ = ["ALL_TERMS", "COR_EFFECT_FLOOR", "EFFECTS", "FLIGHT_TERMS", "FORCE_FLOOR_OF_WEIGHT", "IMPACT_TERMS",
           "PLATES", "STRUCTURE_TERMS", "UNEXPLAINED",
           "AsymmetricRestitution", "ConstantRestitution", "CoulombFriction", "FlightTerm", "GravityTilt",
           "ImpactTerm", "PlateAndSpeed", "PlateSpeedLaw", "QuadraticDrag", "StructureHarmonics", "SumForce",
           "Term", "VelocityDependentRestitution", "ViscousDrag", "catalogue", "cor_values", "force_law",
           "restitution_law"]
