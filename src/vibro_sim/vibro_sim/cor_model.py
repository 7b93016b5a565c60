"""Event-driven COR model (paper Eq. 4-5): exact flights between instantaneous impacts.

Conventions: SI units, lab frame, positive up. ``y0_m`` is the ball centre in the same
frame as ``structure.position`` (so the ball touches the top plate when
y - Y_s(t) = +b and the bottom plate when y - Y_s(t) = -b, b = cavity.free_play_m).

Free flights use exact solutions (:mod:`vibro_sim.flight`); the contact times are
zeros of the gap functions g_top = b - (y - Y_s) and g_bottom = (y - Y_s) + b, found
by :func:`vibro_sim.events.first_root` (never by stepping past a contact) and refined
by Brent's method to 1e-12 s. A plate may move against the structure (``plates``: its own kinematics, e.g.
:class:`vibro_sim.plates.MovedPlate` for a plate that creeps; default the structure's), then g_top =
Y_top(t) + b - y, g_bottom = y - Y_bottom(t) + b. At an
impact v_b+ = v_s - e (v_b- - v_s) with e from the restitution law (v_s the velocity of the plate hit).
When the rebound relative speed is below ``stick_speed_mps`` the ball
is put at rest on the plate; if the plate then pushes it (plate acceleration beyond
the ball's free acceleration) it rides on the plate until the plate's acceleration
releases it (no Zeno loop of ever smaller bounces).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from vibro_model.kinematics import StructureKinematics
from vibro_model.results import Impact

from .events import first_root
from .flight import Segment, Stuck, make_flight_segment
from .forces import ForceLaw, NoForce
from .params import BallCavity
from .restitution import RestitutionLaw

log = logging.getLogger(__name__)

GAP_TOL_M = 1e-12


@dataclass(frozen=True, kw_only=True)
class FlightRecord:
    """A free flight between two events. Flight i ends with impact i.

    ``start_plate``/``end_plate`` are None at the simulation's start/end. ``mean_force_n``
    is m (mean acceleration + g_eff): what a parabola fit (paper Eq. 17) would see.
    ``direction`` is "up" when the ball travels towards the top plate.
    """

    index: int
    t_start_s: float
    t_end_s: float
    force_law: str
    start_plate: str | None
    end_plate: str | None
    direction: str
    mean_force_n: float


@dataclass(frozen=True)
class StuckPhase:
    """The ball rides on ``plate`` from t_start_s to t_end_s."""

    t_start_s: float
    t_end_s: float
    plate: str


@dataclass(kw_only=True)
class SimResult:
    """Output of :func:`simulate_cor` (and the Hertz model): events and an exact trajectory."""

    structure: StructureKinematics
    cavity: BallCavity
    t0_s: float
    t_end_s: float
    impacts: list[Impact] = field(default_factory=list)
    flights: list[FlightRecord] = field(default_factory=list)
    stuck: list[StuckPhase] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    truncated: bool = False
    model: str = "cor"

    def _starts(self) -> np.ndarray:
        cache = getattr(self, "_starts_cache", None)
        if cache is None or cache.size != len(self.segments):
            cache = np.array([s.t0 for s in self.segments])
            self._starts_cache = cache
        return cache

    def _eval(self, t, what: str):
        t_arr = np.atleast_1d(np.asarray(t, dtype=float))
        span = 1e-9 * max(1.0, abs(self.t_end_s))
        if t_arr.size and (t_arr.min() < self.t0_s - span or t_arr.max() > self.t_end_s + span):
            raise ValueError(
                f"time outside the simulated span [{self.t0_s}, {self.t_end_s}] s: "
                f"[{t_arr.min()}, {t_arr.max()}]")
        idx = np.searchsorted(self._starts(), t_arr, side="right") - 1
        idx = np.clip(idx, 0, len(self.segments) - 1)
        out = np.empty_like(t_arr)
        for k in np.unique(idx):
            mask = idx == k
            out[mask] = getattr(self.segments[k], what)(t_arr[mask])
        return out if np.ndim(t) else float(out[0])

    def sample(self, t_s):
        """Ball centre position (m, lab frame) at any time(s) in [t0_s, t_end_s]."""
        return self._eval(t_s, "pos")

    def velocity(self, t_s):
        """Ball velocity (m/s); at an impact instant, the rebound velocity."""
        return self._eval(t_s, "vel")

    def acceleration(self, t_s):
        """Ball acceleration (m/s^2) (free-flight value; impacts are instantaneous)."""
        return self._eval(t_s, "acc")

    def relative_position(self, t_s):
        """Ball centre minus cavity centre, y - Y_s (m): +b touches the top, -b the bottom."""
        return self.sample(t_s) - self.structure.position(t_s)


def sim_impact(index: int, t_s: float, plate: str, cor: float, v_before_mps: float, v_after_mps: float,
               v_structure_mps: float) -> Impact:
    """A simulated impact as the model type: exact, so no std; the flights on each side are not linked."""
    return Impact(index=index, t_s=t_s, plate=plate, cor=cor, cor_std=None, v_ball_before_mps=v_before_mps,
                  v_ball_after_mps=v_after_mps, v_structure_mps=v_structure_mps)


def force_array(force: ForceLaw, v, flight_index: int):
    """Vectorised F(v) (N) for the built-in laws; falls back to a loop."""
    v = np.asarray(v, dtype=float)
    kind = getattr(force, "kind", "ode")
    if kind == "constant":
        return np.full_like(v, force.constant_n(flight_index))
    if kind == "coulomb":
        return -force.magnitude_n * np.sign(v)
    if kind == "viscous":
        return -force.coefficient_ns_per_m * v
    if kind == "quadratic":
        return -force.coefficient_ns2_per_m2 * v * np.abs(v)
    return np.array([force.force_n(float(x), flight_index) for x in v.ravel()]).reshape(v.shape)


def _law_name(force: ForceLaw) -> str:
    return type(force).__name__


@dataclass
class _LoopState:
    """Mutable state of the event loop: time (s), ball position (m) and velocity (m/s), the open flight."""

    t: float
    y: float
    v: float
    flight_start: float
    flight_v0: float
    start_plate: str | None = None
    fi: int = 0
    ii: int = 0
    mode: str = "free"
    stuck_plate: str | None = None
    released_now: bool = False


class _Simulator:
    def __init__(self, structure, cavity, restitution, force, stick_speed_mps, scan_step_s, plates=None):
        self.S = structure
        self.plate_motion = {p: (plates or {}).get(p) or structure for p in ("top", "bottom")}
        self.cav = cavity
        self.law = restitution
        self.force = force if force is not None else NoForce()
        self.b = cavity.free_play_m
        self.m = cavity.mass_kg
        self.g = cavity.g_eff_mps2
        self.stick_speed = stick_speed_mps
        self.step = scan_step_s or min(1e-4, 1.0 / (400.0 * structure.frequency_hz))

    # gap functions ---------------------------------------------------------
    def gap_fn(self, plate: str, seg: Segment):
        S, b = self.plate_motion[plate], self.b
        if plate == "top":
            return lambda t: b - (seg.pos(t) - S.position(t))
        return lambda t: (seg.pos(t) - S.position(t)) + b

    def gap_derivs(self, plate: str, seg: Segment, t: float) -> tuple[float, float, float, float]:
        S = self.plate_motion[plate]
        rel = (float(seg.pos(t) - S.position(t)), float(seg.vel(t) - S.velocity(t)),
               float(seg.acc(t) - S.acceleration(t)), float(seg.jerk(t) - S.jerk(t)))
        if plate == "top":
            return self.b - rel[0], -rel[1], -rel[2], -rel[3]
        return rel[0] + self.b, rel[1], rel[2], rel[3]

    def gap_bounds(self, seg: Segment) -> tuple[float, float, float]:
        a, j, s = seg.bounds()
        return (a + max(p.bound(2) for p in self.plate_motion.values()),
                j + max(p.bound(3) for p in self.plate_motion.values()),
                s + max(p.bound(4) for p in self.plate_motion.values()))

    def leave_delay(self, plate: str, seg: Segment, t: float):
        """At a contact (gap ~ 0): 'impact' if moving in, None if pressed (stick), else a
        delay tau such that the gap is provably > 0 on (t, t + tau]."""
        g0, g1, g2, g3 = self.gap_derivs(plate, seg, t)
        m2, m3, m4 = self.gap_bounds(seg)
        if g1 < -1e-9:
            return "impact"
        if g1 > 1e-9:
            return g1 / m2 if m2 > 0 else math.inf
        if g2 > 1e-7:
            return 1.5 * g2 / m3 if m3 > 0 else math.inf
        if g2 < -1e-7:
            return None
        if g3 > 1e-5:
            return 2.0 * g3 / m4 if m4 > 0 else math.inf
        return None

    def release_fn(self, plate: str, flight_index: int):
        """Positive while the plate presses the ball: s (Y_s'' - a_free), s = +1 bottom, -1 top."""
        S, m, g, force = self.plate_motion[plate], self.m, self.g, self.force
        sgn = 1.0 if plate == "bottom" else -1.0

        def f(t):
            a_free = -g + force_array(force, S.velocity(t), flight_index) / m
            return sgn * (S.acceleration(t) - a_free)
        return f

    def release_bound(self) -> float:
        """A bound on |d/dt| of every plate's :meth:`release_fn` (its slope, for the root scan)."""
        return max(self._release_bound(p) for p in self.plate_motion.values())

    def _release_bound(self, S) -> float:
        m = self.m
        kind = getattr(self.force, "kind", "ode")
        extra = 0.0
        if kind == "viscous":
            extra = self.force.coefficient_ns_per_m / m * S.bound(3)
        elif kind == "quadratic":
            extra = 2 * self.force.coefficient_ns2_per_m2 / m * (S.bound(1) * S.bound(3) + S.bound(2) ** 2)
        return S.bound(4) + extra + 1e-9

    # main loop -------------------------------------------------------------
    def run(self, y0, v0, t0, t_end, max_events) -> SimResult:
        """Simulate from (t0 s, y0 m, v0 m/s) to t_end (s), stopping after ``max_events`` events."""
        res = SimResult(structure=self.S, cavity=self.cav, t0_s=t0, t_end_s=t_end)
        st = self._initial_state(y0, v0, t0)
        events = 0
        while st.t < t_end:
            events += 1
            if events > max_events:
                log.warning("COR model stopped after %d events at t = %.6f s", max_events, st.t)
                res.truncated = True
                break
            if st.mode == "stuck":
                self._ride_plate(res, st, t_end)
            else:
                self._fly(res, st, t_end)
        self._finish(res, st, (t0, y0, v0), t_end)
        return res

    def _initial_state(self, y0: float, v0: float, t0: float) -> _LoopState:
        """The loop's start: the ball at y0 (m, clipped onto the cavity) with v0 (m/s) at t0 (s)."""
        S, b = self.S, self.b
        rel0 = y0 - S.position(t0)
        top = b + float(self.plate_motion["top"].position(t0) - S.position(t0))   # > b where the top plate crept up
        bottom = -b + float(self.plate_motion["bottom"].position(t0) - S.position(t0))
        if rel0 > top + b * 1e-9 + GAP_TOL_M or rel0 < bottom - b * 1e-9 - GAP_TOL_M:
            raise ValueError(f"initial ball position y0 - Y_s(t0) = {rel0:.6g} m is outside the "
                             f"cavity (free play b = {b:.6g} m)")
        rel0 = min(max(rel0, bottom), top)
        return _LoopState(t=t0, y=S.position(t0) + rel0, v=v0, flight_start=t0, flight_v0=v0)

    def _ride_plate(self, res: SimResult, st: _LoopState, t_end: float) -> None:
        """The ball rides ``st.stuck_plate`` until the plate releases it (or t_end, s); then it flies."""
        seg = Stuck(st.t, self.plate_motion[st.stuck_plate], self.b, st.stuck_plate)
        res.segments.append(seg)
        f = self.release_fn(st.stuck_plate, st.fi)
        if float(f(st.t)) > 0.0:
            tr = first_root(f, st.t, t_end, self.release_bound(), self.step)
        else:
            tr = st.t
        tr = t_end if tr is None else tr
        res.stuck.append(StuckPhase(st.t, tr, st.stuck_plate))
        st.t, st.y, st.v = tr, float(seg.pos(tr)), float(seg.vel(tr))
        st.mode, st.flight_start, st.flight_v0, st.start_plate = "free", st.t, st.v, st.stuck_plate
        st.released_now = True

    def _fly(self, res: SimResult, st: _LoopState, t_end: float) -> None:
        """One free-flight piece from the state: to the next impact, a sticking start or the piece's end."""
        seg = make_flight_segment(st.t, st.y, st.v, self.force, st.fi,
                                  mass_kg=self.m, g_eff=self.g, t_limit=t_end)
        t_seg_end = min(seg.t_natural_end, t_end)
        best, go_stuck = self._first_contact(seg, st.t, t_seg_end, st.released_now)
        st.released_now = False
        if go_stuck is not None:
            st.mode, st.stuck_plate = "stuck", go_stuck
            return
        res.segments.append(seg)
        if best is None:
            self._coast(seg, st, t_seg_end)
            return
        tr, plate = best
        vb = float(seg.vel(tr))
        self._close_flight(res, st, tr, vb, plate)
        st.t, st.y, st.v = self.impact(res, tr, plate, vb, st.ii, st.fi, t_end)
        st.ii += 1
        st.fi += 1
        st.flight_start, st.flight_v0, st.start_plate = st.t, st.v, plate

    def _first_contact(self, seg: Segment, t: float, t_seg_end: float, released_now: bool):
        """The first contact of ``seg`` after t (s): ((time s, plate) or None, plate the ball sticks to or None).

        The plate the ball heads for is scanned first; the other only up to that contact.
        """
        m2 = self.gap_bounds(seg)[0]
        best = None
        order = ("top", "bottom") if float(seg.vel(t) - self.S.velocity(t)) >= 0 else ("bottom", "top")
        for plate in order:
            gap = self.gap_fn(plate, seg)
            ta = t
            if float(gap(t)) <= GAP_TOL_M:
                delay = self.leave_delay(plate, seg, t)
                if delay == "impact":
                    return (t, plate), None
                if delay is None:
                    if not released_now:
                        return best, plate
                    delay = 1e-9  # released on the boundary: let it go
                ta = t + delay
            t_stop = t_seg_end if best is None else best[0]
            if ta >= t_stop:
                continue
            r = first_root(gap, ta, t_stop, m2, self.step)
            if r is not None and (best is None or r < best[0]):
                best = (r, plate)
        return best, None

    def _coast(self, seg: Segment, st: _LoopState, t_seg_end: float) -> None:
        """No contact on ``seg``: move the state to its end (t_seg_end, s)."""
        apex = t_seg_end == seg.t_natural_end and seg.label == "flight" \
            and getattr(self.force, "kind", "") in ("coulomb", "quadratic")
        st.t = t_seg_end
        st.y, st.v = float(seg.pos(st.t)), float(seg.vel(st.t))
        if apex:
            st.v = 0.0  # exactly at the apex: the next piece falls (no apex ping-pong)

    def _finish(self, res: SimResult, st: _LoopState, start: tuple[float, float, float], t_end: float) -> None:
        """Close the result: a segment if none, the last flight, the end time if truncated.

        ``start`` is the simulation's (t0 s, y0 m, v0 m/s).
        """
        t0, y0, v0 = start
        if not res.segments:
            res.segments.append(make_flight_segment(t0, y0, v0, self.force, 0,
                                                    mass_kg=self.m, g_eff=self.g, t_limit=t_end))
        if st.mode == "free" and st.flight_start < min(st.t, t_end):
            t_last = min(st.t, t_end)
            self._close_flight(res, st, t_last, float(res.velocity(t_last)), None)
        if res.truncated:
            res.t_end_s = st.t

    def impact(self, res: SimResult, tr: float, plate: str, vb: float, ii: int, fi: int,
               t_end: float) -> tuple[float, float, float]:
        """Instantaneous Newton impact (Eq. 5); returns the state (t, y, v) after it."""
        S, b = self.plate_motion[plate], self.b
        vs = float(S.velocity(tr))
        vrel = vb - vs
        e = float(self.law.cor(plate, vrel, ii))
        vrel_after = -e * vrel
        if abs(vrel_after) < self.stick_speed:
            vrel_after = 0.0
        v_after = vs + vrel_after
        res.impacts.append(sim_impact(ii, tr, plate, e, vb, v_after, vs))
        return tr, float(S.position(tr)) + (b if plate == "top" else -b), v_after

    def _close_flight(self, res: SimResult, st: _LoopState, t_end: float, v_end: float,
                      end_plate: str | None) -> None:
        """Record the flight begun in ``st`` that ends at t_end (s) with velocity v_end (m/s) on ``end_plate``."""
        fi, t_start, v_start, start_plate = st.fi, st.flight_start, st.flight_v0, st.start_plate
        dt = t_end - t_start
        if dt <= 0:
            return
        mean_force = self.m * ((v_end - v_start) / dt + self.g)
        if end_plate is not None:
            direction = "up" if end_plate == "top" else "down"
        elif start_plate is not None:
            direction = "up" if start_plate == "bottom" else "down"
        else:
            direction = "up" if v_end - float(self.S.velocity(t_end)) > 0 else "down"
        res.flights.append(FlightRecord(index=fi, t_start_s=t_start, t_end_s=t_end, force_law=_law_name(self.force),
                                        start_plate=start_plate,
                                        end_plate=end_plate, direction=direction, mean_force_n=mean_force))


def check_span(model: str, y0_m: float, v0_mps: float, t0_s: float, t_end_s: float) -> None:
    """Raise ValueError (naming ``model``) for a non-finite start state or ``t_end_s < t0_s`` (m, m/s, s)."""
    for name, value in (("y0_m", y0_m), ("v0_mps", v0_mps), ("t0_s", t0_s), ("t_end_s", t_end_s)):
        if not math.isfinite(value):
            raise ValueError(f"{model}: {name} must be finite, got {value!r}")
    if t_end_s < t0_s:
        raise ValueError(f"{model}: t_end_s ({t_end_s}) < t0_s ({t0_s})")


@dataclass(frozen=True, kw_only=True)
class CorSolver:
    """Numerical settings of the COR model; :meth:`simulate` runs it (:func:`simulate_cor` with the defaults).

    Attributes
    ----------
    stick_speed_mps : float
        Rebounds slower than this (relative, m/s) are set to zero: the ball sticks.
    scan_step_s : float or None
        Grid of the contact scan (None: min(1e-4 s, T/400)); contacts are found exactly whatever its value.
    max_events : int
        Events (impacts, sticking starts and ends) after which the simulation stops with a warning and
        ``truncated`` set.
    """

    stick_speed_mps: float = 1e-4
    scan_step_s: float | None = None
    max_events: int = 1_000_000

    def simulate(self, structure: StructureKinematics, cavity: BallCavity, restitution: RestitutionLaw,  # noqa: PLR0913
                 force: ForceLaw | None = None, *, y0_m: float = 0.0, v0_mps: float = 0.0,
                 t0_s: float = 0.0, t_end_s: float = 1.5, plates=None) -> SimResult:
        """Simulate the COR model with these settings; parameters, result and errors as :func:`simulate_cor`."""
        check_span("simulate_cor", y0_m, v0_mps, t0_s, t_end_s)
        sim = _Simulator(structure, cavity, restitution, force, self.stick_speed_mps, self.scan_step_s, plates)
        return sim.run(float(y0_m), float(v0_mps), float(t0_s), float(t_end_s), self.max_events)


def simulate_cor(structure: StructureKinematics, cavity: BallCavity, restitution: RestitutionLaw,  # noqa: PLR0913
                 force: ForceLaw | None = None, *, y0_m: float = 0.0, v0_mps: float = 0.0,
                 t0_s: float = 0.0, t_end_s: float = 1.5, plates=None) -> SimResult:
    """Simulate the COR model (instantaneous impacts, Eq. 4-6) from (t0_s, y0_m, v0_mps) to t_end_s.

    The solver's settings (stick speed, scan step, event limit) keep their defaults; to change them use
    ``CorSolver(stick_speed_mps=..., scan_step_s=..., max_events=...).simulate(...)``.

    Parameters
    ----------
    structure : StructureKinematics
        The cavity's motion (m, m/s, m/s^2 against time in s).
    cavity : BallCavity
        Ball and cavity geometry (m) and mass (kg).
    restitution : RestitutionLaw
        The COR of each impact (per plate; constant or a law of the impact speed).
    force : ForceLaw, optional
        A :mod:`vibro_sim.forces` law acting in flight (None: gravity only).
    y0_m : float
        Ball centre (m) in the lab frame (the structure's frame of reference), + up.
    v0_mps : float
        Ball velocity (m/s), + up.
    t0_s, t_end_s : float
        Start and end of the simulation (s).
    plates : mapping, optional
        {"top"/"bottom": the plate's own motion, free play aside} (``position``/``velocity``/``acceleration``/
        ``jerk``/``bound`` like ``structure``; :class:`vibro_sim.plates.MovedPlate`) for a plate that moves against
        the structure (one that creeps); a plate not named moves with the structure. The impacts on a plate take
        its velocity.

    Returns
    -------
    SimResult
        Impacts (time s, velocities m/s, COR), flights, sticking phases and the exact trajectory's segments.

    Raises
    ------
    ValueError
        A non-finite start, a ball outside the cavity, or ``t_end_s < t0_s``.
    """
    return CorSolver().simulate(structure, cavity, restitution, force, y0_m=y0_m, v0_mps=v0_mps,
                                t0_s=t0_s, t_end_s=t_end_s, plates=plates)
