"""Hertz damped contact model (paper Eq. 6-12).

Free flights are the exact solutions of the COR model; at each contact entry (found
exactly as in :mod:`vibro_sim.cor_model`) the contact phase m y'' = -m g_eff + F(v)
+ F_contact is integrated with a stiff solver (scipy ``Radau``) until the exit event
(penetration back to zero). With delta = y - Y_s - b (top, > 0 in contact) or
y - Y_s + b (bottom, < 0 in contact):

    F_contact = -sign(delta) K |delta|^1.5 - c d(delta)/dt      (Eq. 9)

clipped so that the plate never pulls the ball (no tension at the end of a damped
contact). K is Eq. 8 (``BallCavity.contact_stiffness``). The damping comes from the COR
law's e for that impact through Eq. 11-12:

    c = -2 sqrt(K_lin m) ln e / sqrt(pi^2 + ln^2 e),   K_lin = 1.5 K delta_a^0.5

Choice of delta_a (``delta_a="impact"``, the default): the maximum penetration of an
*undamped* Hertz impact at this impact's relative entry speed v,
delta_max = (5 m v^2 / (4 K))^(2/5), so the linearised stiffness follows the speed of
each impact. A number (m) fixes delta_a for all impacts instead. How well the result
restitutes e is measured by :func:`hertz_effective_cor`: with the default the Hertz
impact restitutes less than e (0.536 for 0.6, 0.691 for 0.75, 0.867 for 0.9), the same at
every speed. ``delta_a="calibrated"`` chooses delta_a per impact so that Eq. 11-12
restitute the target e exactly (the paper's stated intent: "c can be chosen to represent
the same energy loss"); numerically it feeds Eq. 11 (at delta_max) the e' found by
:func:`calibrated_eq11_cor`, which is the same c as delta_a = delta_max (c(e')/c(e))^4.

A rebound slower than ``stick_speed_mps`` leaves the ball resting on the plate (handled
as in the COR model: it rides the plate until released; the static Hertz penetration
there, (m g / K)^(2/3) ~ 1e-8 m, is neglected).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import OdeSolution, solve_ivp

from vibro_model.kinematics import StructureKinematics

from .cor_model import SimResult, _Simulator, check_span, sim_impact
from .flight import Segment
from .forces import ForceLaw, NoForce
from .params import BallCavity
from .restitution import Constant, RestitutionLaw

E_MIN = 1e-3  # e -> 0 would need infinite damping
NO_TENSION = True  # clip the contact force so that the plate never pulls the ball


def undamped_max_penetration(cavity: BallCavity, v_mps: float) -> float:
    """delta_max (m) of an undamped Hertz impact at relative speed v: (5 m v^2 / (4 K))^(2/5)."""
    return (5.0 * cavity.mass_kg * v_mps ** 2 / (4.0 * cavity.contact_stiffness)) ** 0.4


def hertz_contact_time(cavity: BallCavity, v_mps: float) -> float:
    """Hertz contact duration (s) of an undamped sphere on a rigid-mass flat at speed v:
    t_c = 2.87 (m^2 / (R E*^2 v))^(1/5)."""
    m, R, E = cavity.mass_kg, cavity.radius_m, cavity.effective_modulus_pa
    return 2.868 * (m * m / (R * E * E * abs(v_mps))) ** 0.2


def damping_coefficient(cavity: BallCavity, e: float, delta_a_m: float) -> float:
    """C (N s/m) of Eq. 11 with K_lin of Eq. 12 at penetration delta_a_m."""
    e = min(max(e, E_MIN), 1.0)
    if e >= 1.0:
        return 0.0
    k_lin = 1.5 * cavity.contact_stiffness * math.sqrt(max(delta_a_m, 0.0))
    le = math.log(e)
    return -2.0 * math.sqrt(k_lin * cavity.mass_kg) * le / math.sqrt(math.pi ** 2 + le ** 2)


class ContactSegment(Segment):
    """Dense solution of the contact phase in the plate's frame: delta(t), delta'(t).

    ``sol`` is the dense solution, or a function that computes it: the simulator passes the contact's
    own integration, run again (the same solver on the same inputs: the same numbers) the first time the
    segment is sampled. A long replay samples few contacts (a contact lasts tens of microseconds, the
    frames come every millisecond); keeping every contact's dense solution cost ~100 kB per impact."""

    label = "contact"

    def __init__(self, t0: float, sol, structure, surface_offset_m: float, accel_fn):
        self.t0 = t0
        self._sol = sol
        self.S = structure
        self.offset = surface_offset_m
        self.accel_fn = accel_fn

    @property
    def sol(self):
        """The dense solution delta, delta' (computed on first use when the segment was given its integration)."""
        if not isinstance(self._sol, OdeSolution):
            self._sol = self._sol()
        return self._sol

    def pos(self, t):
        t = np.asarray(t, dtype=float)
        out = self.S.position(t) + self.offset + self.sol(t)[0]
        return out if np.ndim(t) else float(out)

    def vel(self, t):
        t = np.asarray(t, dtype=float)
        out = self.S.velocity(t) + self.sol(t)[1]
        return out if np.ndim(t) else float(out)

    def acc(self, t):
        ta = np.atleast_1d(np.asarray(t, dtype=float))
        d, dd = self.sol(ta)
        out = np.array([self.accel_fn(a, b, c) for a, b, c in zip(ta, d, dd)])
        out = out + self.S.acceleration(ta)
        return out if np.ndim(t) else float(out[0])

    def jerk(self, t):  # pragma: no cover - not used for contact pieces
        return np.zeros_like(np.asarray(t, dtype=float))

    def bounds(self):  # pragma: no cover
        return math.inf, math.inf, math.inf


class _HertzSimulator(_Simulator):
    def __init__(self, *args, delta_a="impact", rtol=1e-9, **kw):
        super().__init__(*args, **kw)
        self.delta_a = delta_a
        self.rtol = rtol
        self.contact_durations: list[float] = []
        self.effective_cors: list[float] = []

    def impact(self, res, tr, plate, vb, ii, fi, t_end):
        S, b, m, g, K = self.S, self.b, self.m, self.g, self.cav.contact_stiffness
        force = self.force
        vs = float(S.velocity(tr))
        vrel = vb - vs
        e = float(self.law.cor(plate, vrel, ii))
        if self.delta_a in ("impact", "calibrated"):
            d_a = undamped_max_penetration(self.cav, abs(vrel))
        else:
            d_a = float(self.delta_a)
        e_eq11 = calibrated_eq11_cor(self.cav, e) if self.delta_a == "calibrated" else e
        c = damping_coefficient(self.cav, e_eq11, d_a)
        side = 1.0 if plate == "top" else -1.0

        def rel_accel(t, delta, ddot):
            """Delta'' = ball acceleration - plate acceleration (delta = penetration coordinate)."""
            a = -g + force.force_n(ddot + float(S.velocity(t)), fi) / m
            if side * delta > 0:
                fc = -side * K * abs(delta) ** 1.5 - c * ddot
                if NO_TENSION:
                    fc = min(fc, 0.0) if side > 0 else max(fc, 0.0)
                a += fc / m
            return a - float(S.acceleration(t))

        def rhs(t, s):
            return (s[1], rel_accel(t, s[0], s[1]))

        def leave(t, s):
            # +1e-16 m: starts strictly positive (no spurious exit at the entry instant)
            return side * s[0] + 1e-16
        leave.terminal = True
        leave.direction = -1

        tc = hertz_contact_time(self.cav, max(abs(vrel), 1e-6))

        def integrate():
            return solve_ivp(rhs, (tr, t_end), (0.0, vrel), method="LSODA", rtol=self.rtol,
                             atol=(1e-16, 1e-12), first_step=tc / 500.0, max_step=max(tc / 4, 1e-6),
                             events=leave, dense_output=True)

        sol = integrate()
        if not sol.success:  # pragma: no cover
            raise RuntimeError(f"Hertz contact integration failed at t = {tr}: {sol.message}")
        t_out = float(sol.t_events[0][0]) if sol.t_events[0].size else float(sol.t[-1])
        _, v_rel_out = sol.sol(t_out)
        v_rel_out = float(v_rel_out)
        vs_out = float(S.velocity(t_out))
        res.segments.append(ContactSegment(tr, lambda: integrate().sol, S, side * b, rel_accel))
        if abs(v_rel_out) < self.stick_speed:
            v_rel_out = 0.0
        v_out = vs_out + v_rel_out
        self.contact_durations.append(t_out - tr)
        self.effective_cors.append(-v_rel_out / vrel if vrel else float("nan"))
        res.impacts.append(sim_impact(ii, tr, plate, e, vb, v_out, vs))
        return t_out, float(S.position(t_out)) + side * b, v_out


@dataclass(frozen=True, kw_only=True)
class HertzSolver:
    """Settings of the Hertz model; :meth:`simulate` runs it (:func:`simulate_hertz` with the defaults).

    Attributes
    ----------
    delta_a : str or float
        The reference indentation of the damping (Eq. 11-12): ``"impact"`` (each impact's maximum
        penetration), ``"calibrated"`` (chosen per impact so that the achieved COR is e) or a length (m); see
        the module doc.
    stick_speed_mps : float
        Rebounds slower than this (relative, m/s) are set to zero: the ball sticks.
    rtol : float
        Relative tolerance of the contact integration.
    max_events : int
        Events after which the simulation stops with a warning and ``truncated`` set.
    """

    delta_a: str | float = "impact"
    stick_speed_mps: float = 1e-4
    rtol: float = 1e-9
    max_events: int = 1_000_000

    def simulate(self, structure: StructureKinematics, cavity: BallCavity, restitution: RestitutionLaw,
                 force: ForceLaw | None = None, *, y0_m: float = 0.0, v0_mps: float = 0.0,
                 t0_s: float = 0.0, t_end_s: float = 1.5) -> SimResult:
        """Simulate the Hertz damped contact model (Eq. 7-12) with these settings; as :func:`simulate_hertz`."""
        check_span("simulate_hertz", y0_m, v0_mps, t0_s, t_end_s)
        delta_a = self.delta_a
        if delta_a not in ("impact", "calibrated") and not (isinstance(delta_a, (int, float)) and delta_a > 0):
            raise ValueError(f"simulate_hertz: delta_a must be 'impact', 'calibrated' or a positive length (m), "
                             f"got {delta_a!r}")
        sim = _HertzSimulator(structure, cavity, restitution, force, self.stick_speed_mps, None,
                              delta_a=delta_a, rtol=self.rtol)
        res = sim.run(float(y0_m), float(v0_mps), float(t0_s), float(t_end_s), self.max_events)
        res.model = "hertz"
        res.contact_durations_s = sim.contact_durations  # type: ignore[attr-defined]
        res.effective_cors = sim.effective_cors  # type: ignore[attr-defined]
        return res


def simulate_hertz(structure: StructureKinematics, cavity: BallCavity, restitution: RestitutionLaw,
                   force: ForceLaw | None = None, *, y0_m: float = 0.0, v0_mps: float = 0.0,
                   t0_s: float = 0.0, t_end_s: float = 1.5) -> SimResult:
    """Simulate the Hertz damped contact model (Eq. 7-12); same conventions as :func:`simulate_cor`.

    The model's settings (``delta_a``, stick speed, integration tolerance, event limit) keep their
    defaults; to change them use ``HertzSolver(delta_a=..., rtol=..., ...).simulate(...)``.

    Parameters
    ----------
    structure : StructureKinematics
        The cavity's motion (m, m/s, m/s^2 against time in s).
    cavity : BallCavity
        Ball and cavity geometry (m), mass (kg) and contact stiffness.
    restitution : RestitutionLaw
        The target COR e of each impact (Eq. 11).
    force : ForceLaw, optional
        A :mod:`vibro_sim.forces` law acting in flight (None: gravity only).
    y0_m : float
        Ball centre (m) in the lab frame, + up.
    v0_mps : float
        Ball velocity (m/s), + up.
    t0_s, t_end_s : float
        Start and end of the simulation (s).

    Returns
    -------
    SimResult
        As :func:`simulate_cor`'s (see Notes for the impacts' meaning).

    Raises
    ------
    ValueError
        A non-finite start or ``t_end_s < t0_s``.

    Notes
    -----
    In the result, ``impacts[i].t_s`` is the contact entry, ``v_ball_after_mps`` the
    velocity at contact exit and ``cor`` the *target* e given to Eq. 11;
    ``result.contact_durations_s`` and ``result.effective_cors`` hold, per impact, the
    contact time and the achieved -v_rel,out / v_rel,in.
    """
    return HertzSolver().simulate(structure, cavity, restitution, force, y0_m=y0_m, v0_mps=v0_mps,
                                  t0_s=t0_s, t_end_s=t_end_s)


def hertz_single_impact(cavity: BallCavity, e: float, v_mps: float, delta_a: str | float = "impact",
                        rtol: float = 1e-10) -> tuple[float, float]:
    """One impact of the ball on a fixed bottom plate at speed v (no gravity, no force).

    Returns (effective COR = v_out / v_in, contact duration in s).
    """
    cav = BallCavity(mass_kg=cavity.mass_kg, radius_m=cavity.radius_m, free_play_m=cavity.free_play_m,
                     gravity_mps2=0.0, ball_E_pa=cavity.ball_E_pa, ball_nu=cavity.ball_nu,
                     plate_E_pa=cavity.plate_E_pa, plate_nu=cavity.plate_nu)
    S = StructureKinematics(0.0, 1.0)
    t_hit = 1e-4
    y0 = -cav.free_play_m + v_mps * t_hit
    tc = hertz_contact_time(cav, v_mps)
    r = HertzSolver(delta_a=delta_a, rtol=rtol).simulate(S, cav, Constant(e), NoForce(), y0_m=y0, v0_mps=-v_mps,
                                                         t0_s=0.0, t_end_s=t_hit + 20 * tc)
    return r.effective_cors[0], r.contact_durations_s[0]  # type: ignore[attr-defined]


#: The e given to Eq. 11 (grid) and the COR a Hertz impact with delta_a = delta_max then achieves (effective).
#: The relation is dimensionless: the same for every ball, plate and impact speed (the impact is self-similar),
#: so it is a constant, computed once with :func:`hertz_single_impact` (rtol 1e-10, 1 m/s, the default ball);
#: tests/test_sim_hertz.py recomputes it for that ball and a very different one. (Computed in every process it
#: cost ~1 s of CPU per analysis and per simulator node.)
EQ11_GRID = np.concatenate([np.linspace(0.01, 0.99, 50), [0.995, 1.0]])
EQ11_EFFECTIVE = np.array([
    0.08961366735318801, 0.1065143868237512, 0.12031978001218449, 0.13318855543680722, 0.1456975144227311,
    0.15809697456265842, 0.17052071516766806, 0.1830495033068845, 0.1957362429135369, 0.20861769370298167,
    0.2217205755991675, 0.23506502041729274, 0.24866664999532917, 0.2625378931911388, 0.27668885397319926,
    0.2911279062618226, 0.30586211215851866, 0.3208975249698375, 0.33623941404864566, 0.3518924357828168,
    0.367860764649714, 0.38414819964917724, 0.40075824741990634, 0.4176941941550215, 0.4349591645679356,
    0.4525561736119506, 0.47048817467863957, 0.48875810134739234, 0.5073689084081796, 0.526323613020385,
    0.5456253345310176, 0.5652773376159347, 0.585283077473173, 0.6056462505342701, 0.6263708507115257,
    0.6474612356023444, 0.6689222039649325, 0.690759089209937, 0.7129778757484371, 0.7355853451566297,
    0.7585892669057458, 0.7819986472649975, 0.8058240759855514, 0.8300782207524567, 0.8547765552762754,
    0.8799385190457447, 0.9055894891724968, 0.9317645529164034, 0.9585171004993175, 0.9859466942789231,
    0.9929355721684613, 1.0000000020260225])


def calibrated_eq11_cor(cavity: BallCavity, e: float) -> float:
    """The e to put into Eq. 11 (with delta_a = delta_max of the impact) so that the Hertz
    impact actually restitutes ``e``: :data:`EQ11_EFFECTIVE` -> :data:`EQ11_GRID` inverted by interpolation.

    With delta_a = delta_max(v) the effective COR depends neither on the speed nor on the ball and plate
    (``cavity`` is accepted for the callers' sake), so one dimensionless table serves every impact.
    """
    return float(np.interp(min(max(e, 0.0), 1.0), EQ11_EFFECTIVE, EQ11_GRID))


def hertz_effective_cor(cavity: BallCavity, targets=(0.6, 0.75, 0.9), speeds_mps=(0.1, 0.2, 0.5, 1.0, 2.0),
                        delta_a: str | float = "impact") -> list[dict]:
    """Table of the Hertz model's effective COR vs the target e across impact speeds."""
    rows = []
    for e in targets:
        for v in speeds_mps:
            eff, tc = hertz_single_impact(cavity, e, v, delta_a)
            rows.append({"target_cor": e, "speed_mps": v, "effective_cor": eff,
                         "error": eff - e, "contact_time_s": tc})
    return rows
