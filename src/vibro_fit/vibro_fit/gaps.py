"""Impacts inside runs of lost frames (dropped frames, frames without a DIC result).

When frames are lost between two fitted free flights p (before) and q (after), the ball may have struck
once, several times or not at all while the camera saw nothing. One impact is *determined* only when
everything the data say agrees with exactly one (:func:`gap_impact`):

1. the parabolas meet once (Eq. 15) inside the gap, the other root of p - q farther than 4 sigma of
   the impact time from it (:func:`~vibro_fit.impacts.paper_impact` gives the time, the COR and their
   first-order sigmas);
2. plate kinematics: at that time the ball sits on the plate it hits. The plate's level (ball - structure,
   track coordinates) is the median over the impacts already identified on it (at least
   ``MIN_LEVEL_IMPACTS``), its spread their robust std; the extrapolated ball minus the structure there
   must agree within ``K_SIGMA`` sigma (prediction variance of both parabolas plus the level's spread).
   Two impacts (a hop) make the parabolas meet beyond the plate: refused. Between the flights' ends and
   the impact neither extrapolation may pass the other plate;
3. energy: the relative velocity reverses, the COR lies in [0, 1] within ``K_SIGMA`` sigma and, with at
   least ``MIN_LEVEL_IMPACTS`` CORs on that plate, within ``K_SIGMA`` sigma (its own and the plate's
   robust spread) of their median: a double impact restitutes about e^2;
4. accelerometers (impact times on the camera clock, when the clock offset is determined): two or more
   accelerometer impacts in the gap refuse; one must agree with the time within ``K_SIGMA`` sigma plus a
   quarter frame;
5. the gap is no longer than either flight (an extrapolation beyond the data span is not trusted).

A determined impact is an ordinary impact with ``in_gap`` true and ``gap_lost_frames`` (its sigmas are the
propagated ones). Otherwise no impact is reported there and :class:`GapVerdict` says why and how many
impacts the gap may hide: at least 1 when the flights on both sides are not one parabola, at most the
gap's duration over the shortest interval between identified impacts, plus one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .flight_fit import FlightFit
from .impacts import ImpactFit, paper_impact
from .structure_fit import StructureFit

K_SIGMA = 4.0            # agreement required of every consistency test, in sigmas
MIN_LEVEL_IMPACTS = 3    # impacts on a plate before its level (and COR spread) is trusted


@dataclass(kw_only=True)
class GapVerdict:
    """One run of lost frames between two fitted flights: what was decided there.

    ``determined``: one impact found (``impact_index``); else ``may_hide_min``..``may_hide_max`` impacts may
    lie in it, none reported. ``tests``: the numbers behind the decision (z-scores, counts)."""

    t_start_s: float                  # last fitted frame of the flight before
    t_end_s: float                    # first fitted frame of the flight after
    lost_frames: int
    flight_before: int
    flight_after: int
    determined: bool
    reason: str
    impact_index: int | None = None
    may_hide_min: int = 0
    may_hide_max: int = 0
    tests: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"t_start": self.t_start_s, "t_end": self.t_end_s, "lost_frames": self.lost_frames,
                "flight_before": self.flight_before, "flight_after": self.flight_after,
                "determined": self.determined, "impact_index": self.impact_index,
                "may_hide_min": self.may_hide_min, "may_hide_max": self.may_hide_max, "reason": self.reason,
                "tests": dict(self.tests)}

    def warning(self) -> str:
        """One line for the warnings (undetermined gaps only carry the count)."""
        span = f"t {self.t_start_s:.4f}..{self.t_end_s:.4f} s"
        if self.determined:
            return (f"impact {self.impact_index} found inside {self.lost_frames} lost frames ({span}) from the "
                    "flights on both sides (in_gap)")
        count = (f"{self.may_hide_min}" if self.may_hide_min == self.may_hide_max
                 else f"{self.may_hide_min} to {self.may_hide_max}")
        return (f"no impact between flights {self.flight_before} and {self.flight_after} ({span}): "
                f"{self.lost_frames} frames in between have no DIC result and may hide {count} impact(s); "
                f"none reported there: {self.reason}")


def _position_sd_mm(fl: FlightFit, t_s: float) -> float:
    tc = t_s - fl.t_ref_s
    x = np.array([tc * tc, tc, 1.0])
    return float(math.sqrt(max(float(x @ fl.cov @ x), 0.0)))


def _robust_sd(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else float("nan")


def _roots_in(p: FlightFit, q: FlightFit, lo: float, hi: float) -> int:
    """How many times in [lo, hi] the two parabolas meet (p - q about the interval's middle)."""
    tm = 0.5 * (lo + hi)
    ts = np.array([tm - 1e-3, tm, tm + 1e-3])
    d = np.asarray(p.position_mm(ts)) - np.asarray(q.position_mm(ts))
    coef = np.polyfit(ts - tm, d, 2)          # exact: the difference of two parabolas is one
    if abs(coef[0]) < 1e-300:
        roots = np.array([-coef[2] / coef[1]]) if coef[1] != 0 else np.zeros(0)
    else:
        roots = np.roots(coef)
        roots = np.real(roots[np.abs(np.imag(roots)) < 1e-12])
    return int(np.sum((roots + tm >= lo) & (roots + tm <= hi)))


def may_hide(p: FlightFit, q: FlightFit, one_parabola: bool, min_interval_s: float | None) -> tuple[int, int]:
    """(least, most) impacts the gap between ``p`` and ``q`` may hide: at least 1 unless both flights are one
    parabola; at most the gap over the shortest interval between identified impacts, plus one."""
    lo = 0 if one_parabola else 1
    span = max(q.t_start_s - p.t_end_s, 0.0)
    hi = lo if min_interval_s is None or min_interval_s <= 0 else int(math.floor(span / min_interval_s)) + 1
    return lo, max(lo, hi)


@dataclass(frozen=True, kw_only=True)
class GapEvidence:
    """What a gap is judged with besides its two flights: ``prior``, the impacts identified so far (plate
    levels, COR spreads, shortest interval); ``accel_times_s``, accelerometer impacts in the gap (camera clock,
    s; empty without accelerometers or a determined clock offset); ``frame_dt_s``, the frame interval (s);
    ``free_play_mm``, the rig's, for the level of a plate without impacts yet (its opposite's level -+ 2 b)."""

    prior: list[ImpactFit]
    accel_times_s: list[float]
    frame_dt_s: float
    free_play_mm: float | None = None


def gap_impact(index: int, p: FlightFit, q: FlightFit, s_fit: StructureFit, lost_frames: int,
               evidence: GapEvidence) -> tuple[ImpactFit | None, GapVerdict]:
    """The impact between flights ``p`` and ``q`` across ``lost_frames`` lost frames when the data determine
    exactly one (module docstring), and the verdict; ``s_fit``: the structure's local sine."""
    accel_times_s = evidence.accel_times_s
    times = sorted(i.t_s for i in evidence.prior)
    min_iv = float(np.min(np.diff(times))) if len(times) >= 2 else None
    base = dict(t_start_s=float(p.t_end_s), t_end_s=float(q.t_start_s), lost_frames=int(lost_frames),
                flight_before=int(p.index), flight_after=int(q.index))
    tests: dict = {}
    if len(accel_times_s) >= 2:
        tests["accel_impacts_in_gap"] = len(accel_times_s)
        lo, hi = may_hide(p, q, False, min_iv)
        return None, GapVerdict(**base, determined=False, may_hide_min=max(lo, len(accel_times_s)),
                                may_hide_max=max(hi, len(accel_times_s)), tests=tests,
                                reason=f"the accelerometers see {len(accel_times_s)} impacts in it")
    est, reason = _one_meeting(index, p, q, s_fit, tests)
    if reason is None:
        reason = _plate_check(est, p, q, s_fit, evidence, tests)
    if reason is None:
        reason = _energy_check(est, evidence.prior, tests)
    if reason is None:
        reason = _accel_check(est, evidence, tests)
    if reason is not None:
        lo, hi = may_hide(p, q, False, min_iv)
        return None, GapVerdict(**base, determined=False, reason=reason, may_hide_min=lo, may_hide_max=hi,
                                tests=tests)
    found = replace(est, in_gap=True, gap_lost_frames=int(lost_frames))
    return found, GapVerdict(**base, determined=True, reason="one impact fits the flights, the plate and the energy"
                             + (" and the accelerometers" if accel_times_s else ""),
                             impact_index=index, may_hide_min=1, may_hide_max=1, tests=tests)


def _one_meeting(index: int, p: FlightFit, q: FlightFit, s_fit: StructureFit,
                 tests: dict) -> tuple[ImpactFit | None, str | None]:
    """Rules 5 and 1: the impact where the parabolas meet (time, COR and sigmas into ``tests``), and the
    reason to refuse it (None: they meet once inside the gap)."""
    span = q.t_start_s - p.t_end_s
    longest = min(p.t_end_s - p.t_start_s, q.t_end_s - q.t_start_s)
    if span > longest:
        return None, (f"the gap ({span * 1e3:.1f} ms) is longer than a flight beside it ({longest * 1e3:.1f} ms): "
                      "the parabolas cannot be extrapolated across it")
    est = paper_impact(index, p, q, s_fit)
    if est is None:
        return None, "the parabolas on both sides do not meet inside it with a reversed relative velocity"
    sd_t = max(float(est.t_std_s), 1e-9)
    tests.update(t=est.t_s, t_std=sd_t, cor=est.cor, cor_std=est.cor_std)
    n_roots = _roots_in(p, q, p.t_end_s - K_SIGMA * sd_t, q.t_start_s + K_SIGMA * sd_t)
    tests["roots_in_gap"] = n_roots
    if n_roots != 1:
        return est, f"the parabolas meet {n_roots} times in it: the impact time is not unique"
    return est, None


def _known_levels(prior: list[ImpactFit], plate: str, free_play_mm: float | None) -> dict:
    """(median, robust spread) of each plate's level (mm) over the impacts so far (not in gaps); the plate hit,
    when unmeasured, from the other's and the free play."""
    other = "bottom" if plate == "top" else "top"
    levels = {}
    for pl in ("top", "bottom"):
        ys = np.array([i.y_rel_mm for i in prior if i.plate == pl and not getattr(i, "in_gap", False)
                       and math.isfinite(i.y_rel_mm)][-50:])
        if ys.size >= MIN_LEVEL_IMPACTS:
            levels[pl] = (float(np.median(ys)), _robust_sd(ys))
    if plate not in levels and other in levels and free_play_mm:
        sgn = 1.0 if plate == "top" else -1.0
        levels[plate] = (levels[other][0] + sgn * 2.0 * free_play_mm, 2.0 * levels[other][1])
    return levels


def _plate_check(est: ImpactFit, p: FlightFit, q: FlightFit, s_fit: StructureFit, evidence: GapEvidence,
                 tests: dict) -> str | None:
    """Rule 2: the ball on the plate it hits at the impact, and neither flight past the other plate; the
    reason to refuse, or None."""
    free_play_mm = evidence.free_play_mm
    plate, other = est.plate, ("bottom" if est.plate == "top" else "top")
    levels = _known_levels(evidence.prior, plate, free_play_mm)
    if plate not in levels:
        return (f"the {plate} plate's level is not measured yet (fewer than {MIN_LEVEL_IMPACTS} impacts on "
                "it before the gap)")
    lvl, lvl_sd = levels[plate]
    sp, sq = _position_sd_mm(p, est.t_s), _position_sd_mm(q, est.t_s)
    wp, wq = 1.0 / max(sp, 1e-9) ** 2, 1.0 / max(sq, 1e-9) ** 2
    y_ball = (wp * float(p.position_mm(est.t_s)) + wq * float(q.position_mm(est.t_s))) / (wp + wq)
    y_sd = math.sqrt(1.0 / (wp + wq))
    y_rel = y_ball - float(s_fit.position_mm(est.t_s))
    z_level = (y_rel - lvl) / math.sqrt(y_sd ** 2 + lvl_sd ** 2)
    tests.update(y_rel_mm=y_rel, plate_level_mm=lvl, plate_level_sd_mm=lvl_sd, y_sd_mm=y_sd, z_plate=z_level)
    if abs(z_level) > K_SIGMA:
        return (f"the parabolas meet {y_rel - lvl:+.4f} mm from the {plate} plate ({z_level:+.1f} sigma): "
                "more than one impact, or none, fits")
    if other in levels or free_play_mm:
        o_lvl = levels[other][0] if other in levels else lvl + (-2.0 if plate == "top" else 2.0) * free_play_mm
        o_sd = levels[other][1] if other in levels else lvl_sd
        for fl, a, b in ((p, p.t_end_s, est.t_s), (q, est.t_s, q.t_start_s)):
            ts = np.linspace(a, b, 32)
            yr = np.asarray(fl.position_mm(ts)) - np.asarray(s_fit.position_mm(ts))
            beyond = (yr - o_lvl) if plate == "bottom" else (o_lvl - yr)
            if np.any(beyond > K_SIGMA * math.hypot(o_sd, y_sd)):
                return f"a flight beside it reaches the {other} plate inside the gap: more than one impact"
    return None


def _energy_check(est: ImpactFit, prior: list[ImpactFit], tests: dict) -> str | None:
    """Rule 3: a COR not above 1 and, with enough CORs on the plate, close to their median; the reason to
    refuse, or None."""
    plate = est.plate
    e, e_sd = float(est.cor), max(float(est.cor_std), 1e-9)
    if e > 1.0 + K_SIGMA * e_sd:
        return f"the COR would be {e:.4f} +- {e_sd:.4f}, above 1: energy is not conserved by one impact"
    cors = np.array([i.cor for i in prior if i.plate == plate and math.isfinite(i.cor)
                     and not getattr(i, "in_gap", False)][-50:])
    if cors.size >= MIN_LEVEL_IMPACTS:
        stds = np.array([i.cor_std for i in prior if i.plate == plate and math.isfinite(i.cor_std)])
        spread = max(_robust_sd(cors), float(np.median(stds)) if stds.size else 0.0)
        z_cor = (e - float(np.median(cors))) / math.hypot(e_sd, spread)
        tests.update(z_cor=z_cor, plate_cor_median=float(np.median(cors)), plate_cor_spread=spread)
        if abs(z_cor) > K_SIGMA:
            return (f"the COR would be {e:.4f}, {z_cor:+.1f} sigma from the {plate} plate's "
                    f"{float(np.median(cors)):.4f}: not one impact's energy loss")
    return None


def _accel_check(est: ImpactFit, evidence: GapEvidence, tests: dict) -> str | None:
    """Rule 4: one accelerometer impact in the gap agrees with the impact time within K_SIGMA sigma plus a
    quarter frame; the reason to refuse, or None."""
    if not evidence.accel_times_s:
        return None
    sd_t = max(float(est.t_std_s), 1e-9)
    dt = float(evidence.accel_times_s[0]) - est.t_s
    tests["accel_dt_s"] = dt
    if abs(dt) > K_SIGMA * sd_t + 0.25 * evidence.frame_dt_s:
        return f"the accelerometers' impact in it is {dt * 1e3:+.3f} ms from the flights' meeting time"
    return None
