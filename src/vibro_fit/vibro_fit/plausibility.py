"""Physical plausibility of an identification: what no passive impact or friction can give.

A ball bouncing passively in a cavity cannot come off a plate faster (relative to it) than it arrived:
its coefficient of restitution (Eq. 16) lies in [0, 1]. Friction in flight opposes the motion: averaged
over the up and down flights (so that a gravity tilt, which adds the same force to both, cancels) it
takes energy away, never adds it. And the plate under an impact moves as the drive moves it: its speed
never exceeds the drive's velocity amplitude A (2 pi f) (the fitted sine, Eq. 2/13).

A value outside these bounds by more than its uncertainty is not a result but an inconsistency of the
measurement chain. :func:`physical_plausibility` states each as a :class:`Finding` (severity
``"refuse"``: the COR table must not be published) and names the likely cause where the data say it:

- the impacts' structure velocities (each impact's local sine fit, seeded from rig.yaml
  ``excitation.frequency_hz``) disagree with the whole recording's sine while the CORs recomputed
  against that sine lie in [0, 1]: the local fits are wrong; when rig.yaml's frequency disagrees with
  the measured one, that key is named (not the gap or diameter, whose free-play check rests on the
  same local fits);
- a rig.yaml statement (:mod:`vibro_fit.rig_consistency`) about the time base (``camera.fps``).

Thresholds: a one-sided normal test at a family-wise false-alarm probability ``FALSE_ALARM`` (1e-3)
over the n impacts tested (z = Phi^-1(1 - 1e-3 / n): 4.0 for 13 impacts), per impact, per plate
(inverse-variance weighted mean) and over all impacts. A statistical test alone refuses ever smaller biases
as a recording grows (its sigma falls as 1/sqrt(n)), so each bound also has a physical floor: a value is
refused only when it lies beyond the bound by more than its threshold in sigmas AND by more than the floor
(:data:`FRICTION_FLOOR_OF_WEIGHT` of the ball's weight for the friction, :data:`COR_FLOOR` for a COR).
Below the floor the friction's dissipative part is reported as zero within the floor
(:func:`friction_balance`, results.json ``consistency.checks.friction``), neither refused nor claimed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from vibro_model.assemble import ConsistencyStage
from vibro_model.constants import G_MPS2
from vibro_model.drive_envelope import DriveEnvelope
from vibro_model.kinematics import StructureKinematics
from vibro_model.units import mm_to_m

from .segmentation import SegmentationConfig

#: family-wise probability of a false alarm of one test family (impacts, plates, all)
FALSE_ALARM = 1e-3
#: a local structure velocity differs from the whole recording's sine by more than this fraction of the
#: drive's velocity amplitude A w: the local fits do not follow the structure (harmonics of a few % stay below)
STRUCTURE_VELOCITY_TOL = 0.2
#: an impact's structure speed above (1 + this) x the drive's velocity amplitude A w is impossible
DRIVE_SPEED_TOL = 0.1
#: physical floor of the flights' friction, as a fraction of the ball's weight m g. A force F in flight
#: changes the ball's speed over a flight of duration T by F T / m, against a flight speed of order g T / 2:
#: a relative change of ~2 F / (m g), so 1e-3 m g moves an impact speed (and a COR model's prediction) by
#: ~2e-3 relative, ~1e-3 in the COR: below the COR scatter of any real contact and below the COR floor of
#: the discrepancy analysis. It is also what the DIC resolves in one flight's fitted acceleration: a 20 ms
#: flight of 20 frames at 0.25-1 um per frame gives sigma(F) = m sigma(a) ~ 4e-4 to 1.5e-3 m g, so a
#: smaller mean comes from averaging many flights, where the DIC's systematic errors (sub-pixel bias,
#: interpolation) no longer average out (a no-friction synthetic take of 20,000 frames shows -8e-5 m g at 5
#: sigma). Below the floor the friction is zero within it: neither refused nor claimed.
FRICTION_FLOOR_OF_WEIGHT = 1e-3
#: physical floor of a COR outside [0, 1]: the COR change the friction floor above makes (~1e-3); a mean COR
#: of 1.0005 over thousands of impacts is a bias of the measurement chain at that level, not an active impact
COR_FLOOR = 1e-3


@dataclass
class Finding:
    """One cross-check that failed: ``check`` (an identifier), ``message`` (one line: what, the numbers,
    the likely cause), ``keys`` (the rig.yaml keys that are likely wrong; empty when none is), ``evidence``
    (numbers, SI units in the names), ``severity`` ``"refuse"`` (no result may be published) or ``"warn"``,
    ``frame`` (the frame index it locates, for a time-base step)."""

    check: str
    message: str
    keys: list[str] = field(default_factory=list)
    evidence: dict[str, Any] = field(default_factory=dict)
    severity: str = "warn"
    frame: int | None = None

    @property
    def refuses(self) -> bool:
        """True when this finding withholds the results."""
        return self.severity == "refuse"

    def to_dict(self) -> dict:
        """Plain JSON (results.json ``consistency.findings[]``)."""
        out = {"check": self.check, "severity": self.severity, "keys": list(self.keys), "message": self.message,
               "evidence": {k: _plain(v) for k, v in self.evidence.items()}}
        if self.frame is not None:
            out["frame"] = int(self.frame)
        return out


def _plain(v: Any) -> Any:
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(float(v)) else None
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


def z_threshold(n_tests: int, false_alarm: float = FALSE_ALARM) -> float:
    """One-sided normal quantile for ``n_tests`` tests at family-wise probability ``false_alarm``."""
    from scipy.stats import norm

    return float(norm.isf(false_alarm / max(int(n_tests), 1)))


def _weighted_mean(values: np.ndarray, sigmas: np.ndarray) -> tuple[float, float]:
    """Inverse-variance weighted mean and its standard deviation."""
    w = 1.0 / np.maximum(sigmas, 1e-12) ** 2
    return float(np.sum(w * values) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w)))


def _noise_std(impact) -> float:
    """An impact's COR sigma without its model error (:attr:`vibro_model.results.Impact.cor_std_noise`): a COR
    outside [0, 1] by more than the noise is what a wrong model or rig makes, and the model error is made of it."""
    noise = getattr(impact, "cor_std_noise", None)
    return float(noise if noise is not None else (impact.cor_std or 0.0))


def cor_outside_bounds(impacts: Sequence) -> dict | None:
    """Where the CORs leave [0, 1] beyond their sigma and beyond :data:`COR_FLOOR`: per impact, per plate
    (weighted mean), all together.

    ``impacts``: anything with ``index``, ``plate``, ``cor``, ``cor_std`` (its noise share is judged:
    :func:`_noise_std`). Returns None when none does, else {"impacts": [(index, plate, cor, cor_std, z)],
    "plates": {plate: (mean, std, z)}, "all": (mean, std, z),
    "z_limit": {...}, "floor"} listing only the tests that fail (z: distance beyond the bound in sigmas)."""
    rows = [(int(i.index), i.plate, float(i.cor), float(_noise_std(i))) for i in impacts
            if i.cor is not None and np.isfinite(i.cor)]
    if not rows:
        return None
    cor = np.array([r[2] for r in rows])
    sd = np.array([max(r[3], 1e-9) for r in rows])

    def beyond(x: float, s: float) -> float:
        return max(x - 1.0, -x, 0.0) / s

    def outside(x: float, s: float, z_limit: float) -> bool:
        # significant beyond its sigma AND beyond the physical floor
        return beyond(x, s) > z_limit and max(x - 1.0, -x) > COR_FLOOR

    z_one = z_threshold(len(rows))
    bad_impacts = [(r[0], r[1], r[2], r[3], beyond(r[2], max(r[3], 1e-9))) for r in rows
                   if outside(r[2], max(r[3], 1e-9), z_one)]
    z_plate = z_threshold(2)
    plates = {}
    for plate in ("bottom", "top"):
        sel = np.array([r[1] == plate for r in rows])
        if sel.sum() >= 2:
            m, s = _weighted_mean(cor[sel], sd[sel])
            if outside(m, s, z_plate):
                plates[plate] = (m, s, beyond(m, s))
    m, s = _weighted_mean(cor, sd)
    z_all = z_threshold(1)
    together = (m, s, beyond(m, s)) if len(rows) >= 2 and outside(m, s, z_all) else None
    if not bad_impacts and not plates and together is None:
        return None
    return {"impacts": bad_impacts, "plates": plates, "all": together,
            "z_limit": {"impact": z_one, "plate": z_plate, "all": z_all}, "floor": COR_FLOOR}


def cor_against_sine(impacts: Sequence, structure) -> list[float]:
    """Each impact's COR (Eq. 16) with the structure velocity of the whole recording's sine (``structure``:
    a :class:`~vibro_fit.structure_fit.StructureFit`) instead of its local fit; NaN where undefined."""
    out = []
    for i in impacts:
        if i.t_s is None or i.v_ball_before_mps is None or i.v_ball_after_mps is None:
            out.append(math.nan)
            continue
        vs = float(structure.velocity_mps(float(i.t_s)))
        den = float(i.v_ball_before_mps) - vs
        out.append(-(float(i.v_ball_after_mps) - vs) / den if den != 0.0 else math.nan)
    return out


def drive_velocity_amplitude_mps(structure) -> tuple[float, float]:
    """The drive's velocity amplitude A (2 pi f) (m/s) of a structure sine fit, and its standard deviation."""
    a_mm, f = float(structure.amplitude_mm), float(structure.frequency_hz)
    sa, sf = (float(x) if np.isfinite(x) else 0.0 for x in structure.std[:2])
    v = 2.0 * math.pi * a_mm * f * 1e-3
    return v, v * math.hypot(sa / a_mm if a_mm else 0.0, sf / f if f else 0.0)


def _drive_motion(structure, drive: Mapping[str, Any] | None):
    """(velocity at t in m/s, the drive's velocity amplitude A w in m/s): the whole recording's sine, or, where the
    drive moved (results.json ``drive``: not stationary), that sine under the windows' envelope
    (:class:`vibro_model.drive_envelope.DriveEnvelope`) and the envelope's bound on its speed. A frequency drift of
    0.01 Hz/s over a 20 s take bends the phase by 12.6 rad: the take's one sine then averages to 0.13 m/s where the
    plate moves at up to 0.19, and a take was refused for "plate speeds above what the drive gives"."""
    vw, _ = drive_velocity_amplitude_mps(structure)
    envelope = None
    if drive is not None:
        try:
            envelope = DriveEnvelope.of_drive_section(drive, mm_to_m(float(structure.offset_mm)))
        except ValueError:
            envelope = None
    if envelope is None:
        return (lambda t: float(structure.velocity_mps(t))), vw
    moved = envelope.applied_to(StructureKinematics(mm_to_m(float(structure.amplitude_mm)),
                                                    float(structure.frequency_hz), float(structure.phase_rad),
                                                    mm_to_m(float(structure.offset_mm))))
    return (lambda t: float(moved.velocity(t))), float(moved.bound(1))


def structure_at_impacts(impacts: Sequence, structure, drive: Mapping[str, Any] | None = None) -> dict | None:
    """The impacts' structure velocities (their local fits) against the whole recording's sine (under the drive's
    envelope where ``drive``, results.json's section, says it moved: :func:`_drive_motion`): the largest
    difference as a fraction of A w, and the impacts above :data:`DRIVE_SPEED_TOL` beyond A w (faster than the
    drive can move the plate). None without impacts."""
    velocity, vw = _drive_motion(structure, drive)
    rows = [(int(i.index), float(i.t_s), float(i.v_structure_mps)) for i in impacts
            if i.t_s is not None and i.v_structure_mps is not None and np.isfinite(i.v_structure_mps)]
    if not rows or not vw > 0:
        return None
    diff = np.array([abs(v - velocity(t)) for _, t, v in rows]) / vw
    too_fast = [(k, v) for k, _, v in rows if abs(v) > (1.0 + DRIVE_SPEED_TOL) * vw]
    return {"max_difference_of_aw": float(diff.max()), "median_difference_of_aw": float(np.median(diff)),
            "drive_velocity_amplitude_mps": vw, "too_fast": too_fast}


def _frequency_statement(rig_statements: Iterable):
    for r in rig_statements or ():
        if "excitation.frequency_hz" in r.keys or "camera.fps" in r.keys:
            return r
    return None


def _dissipative_part(flights: Sequence) -> tuple[float, float] | None:
    """(D, its standard deviation) in N: D = (median(-F_up) + median(F_down)) / 2 of the free flights' Eq. 17
    friction; None with fewer than 2 free flights in a direction."""
    parts, var = [], 0.0
    for d, sign in (("up", -1.0), ("down", 1.0)):
        rows = [(f.friction_n, f.friction_std_n or 0.0) for f in flights
                if f.free and f.direction == d and f.friction_n is not None]
        if len(rows) < 2:
            return None
        vals = np.array([r[0] for r in rows])
        sd_fit = float(np.median([r[1] for r in rows]))
        spread = 1.4826 * float(np.median(np.abs(vals - np.median(vals))))
        parts.append(sign * float(np.median(vals)))
        var += max(spread, sd_fit) ** 2 * (math.pi / 2.0) / vals.size
    return 0.5 * sum(parts), 0.5 * math.sqrt(var)


def friction_balance(flights: Sequence, mass_kg: float) -> dict | None:
    """The dissipative part of the flights' friction (Eq. 17), averaged over the up and down flights so that a
    constant force (a gravity tilt) cancels: D = (median(-F_up) + median(F_down)) / 2 (N, > 0 opposes the
    motion), judged against its sigma and the physical floor :data:`FRICTION_FLOOR_OF_WEIGHT` m g.

    Returns {"dissipative_n", "std_n", "z" (-D / sigma: > 0 feeds energy in), "z_limit", "weight_fraction",
    "floor_n", "floor_of_weight", "significant", "verdict", "words"} (None with fewer than 2 free flights per
    direction). ``verdict``: ``"feeds_energy"`` (D < 0 beyond z_limit sigmas and beyond the floor: refused),
    ``"zero_within_floor"`` (|D| <= floor, significant or not: reported as zero), ``"dissipative"`` (D above
    the floor) or ``"not_significant"`` (D below minus the floor but within its sigma). ``flights``: model
    Flights (``free``, ``direction``, ``friction_n``, ``friction_std_n``)."""
    est = _dissipative_part(flights)
    if est is None:
        return None
    d_n, sd = est
    weight = mass_kg * G_MPS2
    floor = FRICTION_FLOOR_OF_WEIGHT * weight
    z = -d_n / sd if sd > 0 else math.copysign(math.inf, -d_n)
    z_lim = z_threshold(1)
    significant = abs(z) > z_lim
    if abs(d_n) <= floor:
        verdict = "zero_within_floor"
        words = (f"friction in flight zero within the floor: dissipative part {d_n:.3g} N +- {sd:.2g} N "
                 f"({d_n / weight:+.2g} m g) is below {FRICTION_FLOOR_OF_WEIGHT:g} m g = {floor:.3g} N"
                 + (f" though {abs(z):.1f} sigma from zero (a bias of the measurement chain below what matters for "
                    "the COR)" if significant else ""))
    elif d_n > 0:
        verdict, words = "dissipative", f"friction in flight opposes the motion: dissipative part {d_n:.3g} N"
    elif significant:
        verdict, words = "feeds_energy", f"friction feeds energy into the flights: dissipative part {d_n:.3g} N"
    else:
        verdict = "not_significant"
        words = f"dissipative part {d_n:.3g} N +- {sd:.2g} N: not significantly below zero"
    return {"dissipative_n": d_n, "std_n": sd, "z": z, "z_limit": z_lim, "weight_fraction": d_n / weight,
            "floor_n": floor, "floor_of_weight": FRICTION_FLOOR_OF_WEIGHT, "significant": significant,
            "verdict": verdict, "words": words}


def negative_friction(flights: Sequence, mass_kg: float) -> dict | None:
    """The flights' friction when it feeds energy in (:func:`friction_balance`'s verdict ``"feeds_energy"``:
    D < 0 beyond its sigma, z > z_threshold(1), AND beyond the floor :data:`FRICTION_FLOOR_OF_WEIGHT` m g):
    {"dissipative_n", "std_n", "z", "weight_fraction", "floor_n"}, else None. ``flights``: model Flights
    (``free``, ``direction``, ``friction_n``, ``friction_std_n``)."""
    bal = friction_balance(flights, mass_kg)
    if bal is None or bal["verdict"] != "feeds_energy":
        return None
    return {k: bal[k] for k in ("dissipative_n", "std_n", "z", "weight_fraction", "floor_n")}


def physical_plausibility(impacts: Sequence, flights: Sequence, structure, rig, rig_statements: Iterable = (),
                          structure_moves: bool = True, drive: Mapping[str, Any] | None = None) -> list[Finding]:
    """Findings (severity ``"refuse"``) for CORs outside [0, 1], a friction that feeds energy into the flights
    (each beyond its sigma and its physical floor) and plate speeds above the drive's, each naming its likely
    cause (see the module rules).

    ``impacts``: model Impacts (SI); ``flights``: model Flights; ``structure``: the whole recording's sine
    (:class:`~vibro_fit.structure_fit.StructureFit`); ``rig``: the RigConfig; ``rig_statements``: the
    identification's :class:`~vibro_fit.rig_consistency.RigStatement` list; ``drive``: results.json's ``drive``
    section (the plate's speed is judged against the drive as it moved)."""
    out: list[Finding] = []
    rig_statements = list(rig_statements or ())
    bounds = cor_outside_bounds(impacts)
    local = structure_at_impacts(impacts, structure, drive) if structure_moves else None
    freq = _frequency_statement(rig_statements)
    cause, keys, ev_cause = _structure_cause(impacts, structure, rig, local, freq, structure_moves)
    if bounds is not None:
        ev = {"z_limits": bounds["z_limit"], "floor": bounds["floor"], **ev_cause}
        what = []
        if bounds["all"] is not None:
            m, s, z = bounds["all"]
            what.append(f"mean COR {m:.3f} +- {s:.3f} over all impacts")
            ev["all_mean"], ev["all_std"] = m, s
        for plate, (m, s, z) in bounds["plates"].items():
            what.append(f"{plate} {m:.3f} +- {s:.3f}")
            ev[f"{plate}_mean"], ev[f"{plate}_std"] = m, s
        if bounds["impacts"]:
            worst = max(bounds["impacts"], key=lambda r: r[4])
            what.append(f"{len(bounds['impacts'])} impact(s) alone, e.g. #{worst[0]} ({worst[1]}) "
                        f"{worst[2]:.3f} +- {worst[3]:.3f}")
            ev["impacts_outside"] = [{"index": r[0], "plate": r[1], "cor": r[2], "cor_std": r[3]}
                                     for r in bounds["impacts"]]
        out.append(Finding("cor_outside_0_1",
                           f"COR outside [0, 1] beyond its uncertainty and the floor {COR_FLOOR:g} "
                           f"({'; '.join(what)}): a passive impact cannot return more speed than it received; "
                           f"{cause}", keys, ev, "refuse"))
    if local is not None and local["too_fast"]:
        k, v = max(local["too_fast"], key=lambda r: abs(r[1]))
        out.append(Finding("impact_speed_above_drive",
                           f"plate speed at {len(local['too_fast'])} impact(s) above what the drive gives (impact "
                           f"#{k}: {abs(v):.3f} m/s, drive A 2 pi f = {local['drive_velocity_amplitude_mps']:.3f} "
                           f"m/s); {cause}", keys,
                           {"too_fast": [{"index": a, "v_structure_mps": b} for a, b in local["too_fast"]],
                            **ev_cause}, "refuse"))
    neg = negative_friction(flights, float(rig.ball.mass_kg))
    if neg is not None:
        fr_cause = cause if keys else ("the flights' parabolas or their up/down labels do not describe the ball "
                                       "(check dic.ball_roi and the ball track)")
        out.append(Finding("negative_friction",
                           f"friction feeds energy into the flights: dissipative part {neg['dissipative_n']:.3g} N "
                           f"+- {neg['std_n']:.2g} N (mean of the up and down flights; friction opposes motion; "
                           f"beyond the floor {FRICTION_FLOOR_OF_WEIGHT:g} m g = {neg['floor_n']:.2g} N); "
                           f"{fr_cause}", keys, {**neg, **ev_cause}, "refuse"))
    return out


def _structure_cause(impacts, structure, rig, local, freq, structure_moves: bool) -> tuple[str, list[str], dict]:
    """(words, rig.yaml keys, evidence) of the likely cause of an implausible identification."""
    ev: dict[str, Any] = {}
    if local is not None:
        ev["structure_velocity_difference_of_aw"] = local["max_difference_of_aw"]
    resolved = [c for c in cor_against_sine(impacts, structure) if np.isfinite(c)] if structure_moves else []
    if resolved:
        ev["cor_against_recording_sine_range"] = [float(min(resolved)), float(max(resolved))]
    local_broken = local is not None and local["median_difference_of_aw"] > STRUCTURE_VELOCITY_TOL
    sine_ok = bool(resolved) and min(resolved) >= -0.05 and max(resolved) <= 1.05
    if freq is not None:
        f_nom = float(rig.excitation.frequency_hz)
        f_meas = float(structure.frequency_hz)
        ev.update({"rig_frequency_hz": f_nom, "structure_frequency_hz": f_meas})
        daq = freq.measured.get("daq_excitation_frequency_hz")
        if daq is not None:
            ev["daq_excitation_frequency_hz"] = float(daq)
        key = freq.keys[0] if len(freq.keys) == 1 else " or ".join(freq.keys)
        words = (f"likely cause: rig.yaml {key} disagrees with the measurement (rig.yaml {f_nom:g} Hz, the "
                 f"structure moves at {f_meas:.3f} Hz" + (f", the accelerometers agree at {daq:.3f} Hz" if daq else "")
                 + ")")
        if local_broken:
            words += (f"; the impacts were measured against local structure fits seeded at {f_nom:g} Hz, which miss "
                      f"the structure's velocity by up to {local['max_difference_of_aw']:.0%} of A 2 pi f")
        if sine_ok:
            words += (f" (against the recording's {f_meas:.3f} Hz sine the CORs are {min(resolved):.3f}.."
                      f"{max(resolved):.3f}); the free play measured at the impacts rests on the same fits, so "
                      "structure.gap_mm and ball.diameter_mm are not in question")
        return words + f": correct {key} and run again", list(freq.keys), ev
    if local_broken:
        return (f"likely cause: the local structure fits at the impacts miss the structure's velocity by up to "
                f"{local['max_difference_of_aw']:.0%} of A 2 pi f (check dic.structure_roi and "
                "excitation.frequency_hz)"), [], ev
    return ("no rig.yaml key explains it (check the ball track, dic.ball_roi, and the camera's time base)",
            [], ev)


#: a flight falling faster than g by more than this fraction is a scale or time-base error (rig_consistency), not
#: an orientation: a tilt only takes gravity away
FASTER_THAN_G_TOL = 0.05


def axis_gravity(flights: Sequence, *, g_axis_mps2: float, axis_tilt_deg: float, noise_mm: float,
                 motion_state: str | None, n_cor_impacts: int) -> Finding | None:
    """The rig's declared orientation (rig.yaml ``setup.axis_tilt_deg``) against what the flights show; a refusing
    :class:`Finding` naming the key, or None.

    - Most fitted flights (at least 3) that are parabolas within the noise fall at an acceleration whose median
      is farther from the declared axis' gravity g cos(theta) than a free flight's force allows
      (``max_friction_g`` of the weight, the segmentation's bound), and at most g (a tilt only takes gravity
      away; faster is a scale or time-base error, :mod:`.rig_consistency`): the axis is not where rig.yaml says
      (a horizontal rig described as vertical finds no free flight, hence no impact). The tilt the fall implies,
      acos(-a / g), is named.
    - An axis declared tilted (theta > 0) on which the ball moves but no impact gets a COR: vibro cannot measure
      this motion there (flights too short, or a force in flight beyond the free-flight bound); it is said, not
      published as a recording without impacts.

    ``flights``: the identification's FlightFits; ``noise_mm`` the ball's position noise (mm)."""
    cfg = SegmentationConfig()
    limit = cfg.rms_factor * float(noise_mm or 0.0) + cfg.rms_floor_mm
    shaped = [f for f in flights if f.fitted and np.isfinite(f.acceleration_mps2) and f.rms_residual_mm <= limit]
    off = [f for f in shaped if abs(f.acceleration_mps2 + g_axis_mps2) > cfg.max_friction_g * G_MPS2]
    key = "setup.axis_tilt_deg"
    if len(off) >= 3 and len(off) >= 0.5 * len(shaped):
        a_med = float(np.median([f.acceleration_mps2 for f in off]))
        if abs(a_med + g_axis_mps2) > cfg.max_friction_g * G_MPS2 and abs(a_med) <= (1 + FASTER_THAN_G_TOL) * G_MPS2:
            implied = math.degrees(math.acos(min(max(-a_med / G_MPS2, -1.0), 1.0)))
            ev = {"fall_acceleration_mps2": -a_med, "declared_axis_gravity_mps2": g_axis_mps2,
                  "declared_axis_tilt_deg": axis_tilt_deg, "implied_axis_tilt_deg": implied,
                  "flights_off": len(off), "flights_fitted": len(shaped)}
            return Finding("axis_gravity",
                           f"the flights fall at {-a_med:.2f} m/s^2 along the axis ({len(off)} of {len(shaped)} "
                           f"parabolas), not at the {g_axis_mps2:.2f} m/s^2 = g cos({axis_tilt_deg:g} deg) of rig.yaml "
                           f"{key} {axis_tilt_deg:g}: no flight is free under that gravity, so no impact can be "
                           f"measured; the axis is about {implied:.0f} deg from vertical: set {key} (0 vertical, 90 "
                           "horizontal) and run again", [key], ev, "refuse")
    if axis_tilt_deg > 0.0 and n_cor_impacts == 0 and motion_state in ("ball_moving", "impacting"):
        reasons = sorted({f.reason.split(":")[0] for f in flights if not f.is_free and f.reason})
        ev = {"declared_axis_tilt_deg": axis_tilt_deg, "declared_axis_gravity_mps2": g_axis_mps2,
              "flights_fitted": len(shaped), "flights_free": sum(bool(f.is_free) for f in flights)}
        return Finding("axis_gravity",
                       f"the ball moves but no impact could be measured on the axis rig.yaml {key} declares "
                       f"{axis_tilt_deg:g} deg from vertical (gravity along it {g_axis_mps2:.2f} m/s^2): "
                       f"{ev['flights_free']} free flight(s) of {len(flights)} fitted"
                       + (f" ({'; '.join(reasons[:3])})" if reasons else "")
                       + f"; check {key}; an impact needs a free flight on each side (on a horizontal axis a "
                       "straight line, the guide rods' friction below half the ball's weight)", [key], ev, "refuse")
    return None


#: rig.yaml keys whose statement rests on the impacts' local structure fits (the free play)
_GEOMETRY_KEYS = {"structure.gap_mm", "ball.diameter_mm", "camera.mm_per_px"}


def friction_withheld(findings: Iterable[Finding]) -> bool:
    """A refusal says the flights' friction is implausible: it is withheld with the COR table."""
    return any(f.check == "negative_friction" and f.refuses for f in findings)


def findings_from_section(section: dict) -> list[Finding]:
    """The findings of a ``consistency`` section as recorded (results.json, or the trajectory_fitter's
    /diagnostics value): the inverse of :meth:`Finding.to_dict`."""
    return [Finding(f.get("check", ""), f.get("message", ""), list(f.get("keys", ())), dict(f.get("evidence", {})),
                    f.get("severity", "warn"), f.get("frame")) for f in section.get("findings", [])]


def consistency_stage(findings: Sequence[Finding], section: dict | None, *, refused_line: str = "",
                      problem: str = "") -> ConsistencyStage:
    """The cross-checks as the results assembler takes them (:class:`vibro_model.assemble.ConsistencyStage`):
    ``section`` (results.json ``consistency``), one warning per finding, and what a refusal withholds: the
    refusal's line (``refused_line``, the trajectory_fitter's words when a bag recorded them, else the first
    refusing finding's message), the friction when it is the implausible part (:func:`friction_withheld`),
    and the rig.yaml statements that are the refusal's consequences: the free play, measured against
    structure fits seeded at a wrong frequency or time base (:data:`_GEOMETRY_KEYS`). ``problem``: why a
    recorded section could not be read (a warning)."""
    refused = bool(refused_line) or any(f.refuses for f in findings) or bool((section or {}).get("refused"))
    refusal = None
    if refused:
        refusal = refused_line or next((f.message for f in findings if f.refuses),
                                       "the trajectory_fitter refused the run")
    frequency_cause = any(f.refuses and {"excitation.frequency_hz", "camera.fps"} & set(f.keys)
                          and "cor_against_recording_sine_range" in f.evidence for f in findings)
    return ConsistencyStage(section=section, warnings=[f"consistency: {f.message}" for f in findings],
                            refusal=refusal, withhold_friction=friction_withheld(findings),
                            consequence_keys=frozenset(_GEOMETRY_KEYS) if frequency_cause else frozenset(),
                            problem=problem)
