"""The named passes of :func:`vibro_fit.identify.identify`, each with explicit inputs and outputs.

In the order ``identify`` runs them: :func:`validate_inputs`; :func:`structure_pass` (structure sine, noise,
the frequency the motion runs at); :func:`run_streaming` (segmentation, flights, COR impacts: the streaming
fitter); :func:`accel_pass` (accelerometer impacts, clock offset, coverage); :func:`contact_pass` (the ball
riding a plate); :func:`impact_pass` (plate levels, the ``joint`` refinement); :func:`hop_pass` (short hops
measured on the plate, merged with the flights and impacts); :func:`friction_pass`; :func:`flight_warnings`;
:func:`landing_pass` (impacts without a COR); :func:`unseen_pass` (accelerometer impacts the camera misses);
:func:`regime_pass`, :func:`motion_pass` and :func:`rig_pass`. Units: mm, s, m/s, Hz, N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vibro_io.accel import AccelData
from vibro_io.dictrack import DicTrack, FrameTrack
from vibro_io.rig import RigConfig
from vibro_model.errors import RecordingError

from .accel_impacts import (
    AccelAnalysis,
    ClockOffset,
    analyse_accel,
    estimate_clock_offset,
    expected_timing_noise_s,
    judge_residuals,
)
from .contacts import ContactPhase, contact_frames, find_contacts, refine_contacts
from .coverage import FrameCoverage, frame_coverage
from .drive import DriveModel, fit_drive
from .flight_fit import FlightFit
from .gaps import GapVerdict
from .hops import HopChain, acceleration_prior, chains_after_open_flights
from .impacts import ImpactFit, joint_impact
from .landings import Landing, find_landings
from .methods import METHODS
from .motion_state import MotionState, classify_motion, structure_moves
from .regimes import Regime, RegimeEvidence, classify_regime, y_rel_range
from .rig_consistency import RigStatement, check_rig, excitation_on_daq_clock_hz
from .segmentation import SegmentationConfig, difference_noise_mm, noise_sigma_mm, plate_levels
from .streaming import StreamingFitter
from .structure_fit import StructureFit, fit_structure


# ------------------------------------------------------------------ records passed between the passes
@dataclass(frozen=True, kw_only=True)
class MotionBasis:
    """What :func:`structure_pass` measures before any segmentation."""

    structure: StructureFit     # the structure's sine (mm, Hz, rad)
    moving: bool                # the structure moves beyond DIC noise
    f_motion_hz: float          # the structure's fitted frequency when it moves, else rig.yaml's nominal (Hz)
    noise_mm: float             # ball position noise (mm; 0 when it cannot be estimated)
    warnings: list[str] = field(default_factory=list)
    #: the structure track's noise (mm): the sine's rms residual, or less where the drive moved over the take and
    #: that residual holds the drive's change (:func:`~vibro_fit.segmentation.difference_noise_mm`)
    structure_noise_mm: float = 0.0


@dataclass(frozen=True, kw_only=True)
class StreamingSettings:
    """The streaming fitter's settings, the same for every run of it in one identification."""

    frequency_hz: float          # nominal excitation (Hz)
    noise_mm: float | None       # ball position noise (mm)
    method: str                  # identify's method; "joint" runs the fitter as "paper"
    config: SegmentationConfig
    weights: str | None
    free_play_mm: float | None   # the rig's, for impacts inside lost frames (vibro_fit.gaps)


@dataclass(frozen=True, kw_only=True)
class AccelPass:
    """The accelerometers' contribution (all None without accelerometers)."""

    analysis: AccelAnalysis | None = None
    offset: ClockOffset | None = None
    coverage: FrameCoverage | None = None
    camera_times_s: list[float] | None = None   # their impacts on the camera clock; None: offset not determined
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True, kw_only=True)
class HopPass:
    """Flights and impacts with the hop chains merged in, the chains, and the refined contact phases."""

    flights: list[FlightFit]
    impacts: list[ImpactFit]
    chains: list[HopChain]
    contacts: list[ContactPhase]


# ------------------------------------------------------------------ validation and the streaming fitter
def validate_inputs(track: DicTrack, method: str, weights: str | None) -> None:
    """Raise RecordingError for an unknown ``method`` or ``weights``, or a track too short to identify."""
    if weights not in (None, "none", "dic_valid"):
        raise RecordingError(f"identify: unknown weights {weights!r} (none, dic_valid)")
    if method not in METHODS:
        raise RecordingError(f"identify: unknown method {method!r} (choose from {', '.join(METHODS)})")
    n = len(track)
    if n < 20:
        raise RecordingError(f"DIC track: {n} frames, need at least 20 to identify the motion")
    if np.any(np.diff(track.t_s) <= 0):
        k = int(np.flatnonzero(np.diff(track.t_s) <= 0)[0]) + 1
        raise RecordingError(f"DIC track: frame {int(track.frame[k])}: time {track.t_s[k]} s does not increase")
    good = track.good
    if good.sum() < 20:
        raise RecordingError(f"DIC track: only {int(good.sum())} of {n} frames are usable (not lost, finite)")


def track_rows(track: DicTrack):
    """The FrameTrack rows of a DicTrack, in order."""
    for k in range(len(track)):
        yield FrameTrack(frame=int(track.frame[k]), t_s=float(track.t_s[k]), ball_mm=float(track.ball_mm[k]),
                         structure_mm=float(track.structure_mm[k]), ball_valid=int(track.ball_valid[k]),
                         structure_valid=int(track.structure_valid[k]),
                         ball_zncc=float(track.ball_zncc[k]), structure_zncc=float(track.structure_zncc[k]),
                         lost=bool(track.lost[k]))


def run_streaming(track: DicTrack, settings: StreamingSettings, *, accel_times_s=(),
                  contact_frames: set[int] | None = None) -> StreamingFitter:
    """Run the streaming fitter over a whole track (``accel_times_s``: accelerometer impact times on the
    camera clock, s; ``contact_frames``: track indices of the ball riding a plate, :mod:`vibro_fit.contacts`)."""
    method = "paper" if settings.method == "joint" else settings.method
    sf = StreamingFitter(settings.frequency_hz, noise_mm=settings.noise_mm, method=method, config=settings.config,
                         weights=settings.weights, free_play_mm=settings.free_play_mm, contact_frames=contact_frames)
    for tx in accel_times_s:
        sf.push_accel_impact(tx)
    for row in track_rows(track):
        sf.push(row)
    sf.finish()
    return sf


# ------------------------------------------------------------------ structure
def structure_pass(track: DicTrack, rig: RigConfig) -> MotionBasis:
    """The structure's sine over the good frames, whether it moves, the frequency of the motion (Hz) and the
    ball's noise (mm), with the warnings on an off-nominal frequency and on lost frames."""
    good = track.good
    t, st = track.t_s, track.structure_mm
    f_nom = rig.excitation.frequency_hz
    structure = fit_structure(t[good], st[good])
    structure_noise = structure_noise_mm(track, structure)
    moving = structure_moves(structure.amplitude_mm, float(structure.std[0]), structure_noise)
    warnings: list[str] = []
    if moving and abs(structure.frequency_hz - f_nom) > 0.05 * f_nom:
        warnings.append(f"structure frequency {structure.frequency_hz:.3f} Hz differs from the nominal "
                        f"{f_nom:g} Hz (rig.yaml excitation.frequency_hz) by more than 5 %")
    if good.sum() < len(track):
        warnings.append(f"{int(len(track) - good.sum())} lost/invalid frames excluded")
    noise = noise_sigma_mm(t[good], track.ball_mm[good], rig.g_axis_mps2)
    if not np.isfinite(noise):
        noise = 0.0
    return MotionBasis(structure=structure, moving=moving, f_motion_hz=structure.frequency_hz if moving else f_nom,
                       noise_mm=noise, warnings=warnings, structure_noise_mm=structure_noise)


def structure_noise_mm(track: DicTrack, structure: StructureFit) -> float:
    """The structure track's noise (mm): the take's sine's rms residual, or its differences' noise
    (:func:`~vibro_fit.segmentation.difference_noise_mm`) where that is smaller. The residual is the noise only
    while the drive holds still: a frequency drift of 0.02 Hz/s over an 8 s take left 0.32 mm of residual on a
    1.47 mm sine, which then "did not move beyond DIC noise" and made every plate contact last 5 ms. The
    differences miss a drive that is fast against the frame rate; the smaller of the two holds either way."""
    good = track.good
    y = np.where(good, np.asarray(track.structure_mm, float), np.nan)
    diff = difference_noise_mm(y, np.asarray(track.frame))
    resid = float(structure.rms_residual_mm)
    return min(resid, diff) if math.isfinite(diff) else resid


def drive_pass(track: DicTrack, basis: MotionBasis) -> tuple[DriveModel | None, list[str]]:
    """Whether the drive held still over the take (:mod:`vibro_fit.drive`: the structure track in windows of a few
    drive cycles against the global sine of ``basis``), and the warning when it did not; (None, []) when the
    structure does not move. Changes nothing else: a stationary drive keeps the global sine."""
    good = track.good
    drive = fit_drive(track.t_s[good], track.structure_mm[good], basis.structure, basis.moving)
    warning = drive.warning() if drive is not None else None
    return drive, [warning] if warning else []


# ------------------------------------------------------------------ accelerometers and clock offset
def accel_pass(accel: AccelData | None, sf: StreamingFitter, *, track: DicTrack, rig: RigConfig,
               basis: MotionBasis, config: SegmentationConfig, highpass_hz: float,
               analysis: AccelAnalysis | None = None) -> AccelPass:
    """Accelerometer impacts (high-pass corner ``highpass_hz``, Hz; ``analysis``: as detected on ``accel`` before,
    else detected here), the camera-to-DAQ clock relation (offset and, when significant, rate) from the first
    streaming run ``sf``, their times on the camera clock when the offset is determined (mapped with the rate), a
    warning when the clock residuals exceed the timing noise, and the filmed interval's coverage by the
    accelerometer record."""
    if accel is None:
        return AccelPass()
    if analysis is None:
        analysis = analyse_accel(accel, basis.f_motion_hz, highpass_hz=highpass_hz)
    warnings = list(analysis.warnings)
    acc_t = [i.t_s for i in analysis.impacts]
    offset = _clock_offset(acc_t, sf, track=track, rig=rig, basis=basis, config=config, accel=accel)
    camera_times = None
    if offset is not None and offset.determined:
        camera_times = offset.camera_s(acc_t) if acc_t else []
        if offset.residual_warning:
            warnings.append(offset.residual_warning)
    elif acc_t:
        warnings.append(_offset_unknown(offset, accel, track.t_s))
    clock = offset.line if offset is not None and offset.determined else None
    coverage = frame_coverage(track.t_s, accel.t_s, acc_t, clock, 1.0 / rig.camera.fps)
    if coverage.message():
        warnings.append(coverage.message())
    return AccelPass(analysis=analysis, offset=offset, coverage=coverage, camera_times_s=camera_times,
                     warnings=warnings)


def _offset_unknown(offset: ClockOffset | None, accel: AccelData, t: np.ndarray) -> str:
    """The warning for an accelerometer record whose clock offset is not determined (durations in s)."""
    why = offset.reason if offset is not None else "no accelerometer impact lies within 1 s of a DIC impact"
    durations = (f"; the accelerometer record lasts {float(accel.t_s[-1] - accel.t_s[0]):.3f} s, "
                 f"the video {float(t[-1] - t[0]):.3f} s")
    return (f"clock offset unknown: not determined ({why}{durations}); accelerometer impacts are "
            "not paired with the camera's, segmentation from DIC only")


def _clock_offset(acc_t: list[float], sf: StreamingFitter, *, track: DicTrack, rig: RigConfig,
                  basis: MotionBasis, config: SegmentationConfig, accel: AccelData) -> ClockOffset | None:
    """Camera-to-DAQ offset from the COR impacts; when that is not determined, from the COR impacts plus the
    landings (impacts without a COR, located to a frame or better: tolerance 0.5 ms + half a frame)."""
    t = track.t_s
    spans = {"accel_span_s": (float(accel.t_s[0]), float(accel.t_s[-1])),
             "camera_span_s": (float(t[0]), float(t[-1]))}
    period_s = 1.0 / basis.f_motion_hz
    frame_s = 1.0 / rig.camera.fps
    offset = estimate_clock_offset(acc_t, [i.t_s for i in sf.impacts], period_s=period_s, **spans)
    if offset is not None and offset.determined:
        noise_s = expected_timing_noise_s(accel.sample_rate_hz, [i.t_std_s for i in sf.impacts], frame_s)
        return judge_residuals(offset, noise_s)
    levels = plate_levels(list(sf.impacts), rig.free_play_mm)
    landings = find_landings(sf.flights, sf.impacts, clusters=sf.clusters, short_flights=sf.short_flights,
                             structure=basis.structure, plate_levels=levels, track=track,
                             max_impact_frames=config.max_impact_frames)
    marks = sorted([i.t_s for i in sf.impacts] + [x.t_s for x in landings])
    alt = estimate_clock_offset(acc_t, marks, period_s=period_s, tol_s=0.0005 + 0.5 / rig.camera.fps, **spans)
    if alt is not None and (alt.determined or offset is None or alt.n_matched > offset.n_matched):
        # landings are located to a frame: their times carry a frame's quantisation
        return judge_residuals(alt, expected_timing_noise_s(accel.sample_rate_hz, (), frame_s))
    return offset


# ------------------------------------------------------------------ contacts, impacts, hops
def contact_pass(track: DicTrack, sf: StreamingFitter, basis: MotionBasis,
                 rig: RigConfig) -> tuple[list[ContactPhase], set[int]]:
    """Contact phases (the ball riding a plate) from the positions, with the plate levels of ``sf``'s impacts
    where known, and the track indices of their good frames."""
    sig_rel = float(np.hypot(basis.noise_mm, basis.structure_noise_mm))
    levels0 = {k: v for k, v in plate_levels(list(sf.impacts)).items() if k in ("top", "bottom")}
    contacts = find_contacts(track, sig_rel, rig.free_play_mm, levels0)
    return contacts, contact_frames(contacts, track.good)


def impact_pass(sf: StreamingFitter, track: DicTrack, rig: RigConfig, method: str,
                noise_mm: float) -> tuple[list[ImpactFit], dict]:
    """The final run's COR impacts (refitted in pairs constrained to the plate for ``method`` "joint") and the
    plate levels measured from them (mm)."""
    impacts = list(sf.impacts)
    levels = plate_levels(impacts, rig.free_play_mm)
    if method == "joint":
        impacts = _joint_refit(impacts, sf.flights, levels, track, noise_mm)
    return impacts, levels


def acceleration_priors(flights: list[FlightFit]) -> dict[str, tuple[float, float]]:
    """Per flight direction ("up"/"down"): (median, spread) of the quadratic coefficient A (mm/s^2) over the
    free flights, the spread being the between-flight std (robust std minus the fits' own noise, in
    quadrature), floored at 0.3 x the median fit std so that a constant friction never gets infinite weight."""
    out = {}
    for d in ("up", "down"):
        fl = [f for f in flights if f.is_free and f.direction == d]
        if len(fl) < 5:
            continue
        a = np.array([f.coef[0] for f in fl])
        var_fit = np.array([f.cov[0, 0] for f in fl])
        robust_sd = 1.4826 * float(np.median(np.abs(a - np.median(a))))
        between = robust_sd ** 2 - float(np.median(var_fit))
        floor = 0.3 * float(np.sqrt(np.median(var_fit)))
        out[d] = (float(np.median(a)), max(float(np.sqrt(max(between, 0.0))), floor))
    return out


def _prior_for(fl: FlightFit, priors: dict) -> tuple[float, float] | None:
    """The direction's prior, unless this flight's own A disagrees with it by more than 3 sigma (an
    atypical flight keeps its own acceleration)."""
    pr = priors.get(fl.direction)
    if pr is None:
        return None
    if abs(fl.coef[0] - pr[0]) > 3.0 * np.sqrt(fl.cov[0, 0] + pr[1] ** 2):
        return None
    return pr


def _joint_refit(impacts: list[ImpactFit], flights: list[FlightFit], levels: dict, track: DicTrack,
                 noise_mm: float) -> list[ImpactFit]:
    """Each impact between two known flights on a plate of known level refitted jointly
    (:func:`vibro_fit.impacts.joint_impact`) with the direction's acceleration prior."""
    by_index = {f.index: f for f in flights}
    priors = acceleration_priors(flights)
    refined = []
    for est in impacts:
        y_plate = levels.get(est.plate) if est.plate in ("top", "bottom") else None
        p, q = by_index.get(est.flight_before), by_index.get(est.flight_after)
        if y_plate is None or p is None or q is None:
            refined.append(est)
            continue
        refined.append(joint_impact(est, p, q, track.t_s, track.ball_mm, y_plate,
                                    accel_priors=(_prior_for(p, priors), _prior_for(q, priors)), noise_mm=noise_mm))
    return refined


def hop_pass(sf: StreamingFitter, impacts: list[ImpactFit], levels: dict, *, contacts: list[ContactPhase],
             cframes: set[int], track: DicTrack, rig: RigConfig, basis: MotionBasis) -> HopPass:
    """The hop chains after the flights no COR impact closes (:func:`vibro_fit.hops.chains_after_open_flights`),
    merged into the flights and impacts (renumbered), and the contact phases' physical start and end."""
    chains = chains_after_open_flights(sf.flights, impacts, levels, contacts=contacts, cframes=cframes,
                                       track=track, f_hz=basis.f_motion_hz, noise_mm=float(basis.noise_mm))
    flights = list(sf.flights)
    if chains:
        flights, impacts = _merge_chains(flights, impacts, chains, sf.gaps)
    if contacts:
        prior = acceleration_prior(sf.flights)
        contacts = refine_contacts(contacts, chains, basis.structure, 2.0e-3 * prior[0] if prior else None,
                                   1.0 / rig.camera.fps)
    return HopPass(flights=flights, impacts=impacts, chains=chains, contacts=contacts)


def _merge_chains(flights: list[FlightFit], impacts: list[ImpactFit], chains: list[HopChain],
                  gaps: list[GapVerdict]) -> tuple[list[FlightFit], list[ImpactFit]]:
    """Flights and impacts with the chains' hops and impacts, in time order and numbered again (the
    impacts' flight_before/after and the gaps' flights follow)."""
    gone_f = {id(c.replaces[1]) for c in chains if c.replaces is not None}
    gone_i = {id(c.replaces[0]) for c in chains if c.replaces is not None}
    flights = [f for f in flights if id(f) not in gone_f]
    impacts = [i for i in impacts if id(i) not in gone_i]
    flights = sorted(flights + [h for c in chains for h in c.hops], key=lambda f: f.t_start_s)
    new_f = {f.index: j for j, f in enumerate(flights)}
    impacts = sorted(impacts + [i for c in chains for i in c.impacts], key=lambda i: i.t_s)
    for j, f in enumerate(flights):
        f.index = j
    for j, i in enumerate(impacts):
        i.index = j
        i.flight_before = new_f.get(i.flight_before, i.flight_before)
        i.flight_after = new_f.get(i.flight_after, i.flight_after)
    for g in gaps:
        g.flight_before = new_f.get(g.flight_before, g.flight_before)
        g.flight_after = new_f.get(g.flight_after, g.flight_after)
    return flights, impacts


# ------------------------------------------------------------------ friction and the flights' warnings
def friction_pass(flights: list[FlightFit], structure: StructureFit, mass_kg: float,
                  g_mps2: float) -> list[dict]:
    """Friction force (N) of every flight of the final run; a flight without a direction gets it here (the
    sign of the relative velocity at mid-flight: no impact next to it)."""
    friction = []
    for fl in flights:
        if not fl.direction:
            tm = 0.5 * (fl.t_start_s + fl.t_end_s)
            fl.direction = "up" if fl.velocity_mps(tm) - structure.velocity_mps(tm) > 0 else "down"
        f_n, f_std = fl.friction_n(mass_kg, g_mps2)
        friction.append({"flight": fl.index, "friction_n": f_n, "friction_std_n": f_std,
                         "direction": fl.direction, "free": fl.is_free})
    return friction


def flight_warnings(sf: StreamingFitter, levels: dict, free_play_mm: float) -> list[str]:
    """Warnings on the measured free play (mm) against rig.yaml's, on flights that are not free, and the
    streaming fitter's rejections."""
    warnings = []
    b = free_play_mm
    if "free_play_mm" in levels and abs(levels["free_play_mm"] - b) > 0.05 * b:
        warnings.append(f"measured free play {levels['free_play_mm']:.3f} mm (half the ball's relative travel "
                        f"between the plates) differs from rig.yaml (gap - diameter)/2 = {b:.3f} mm by more than 5 %")
    for fl in sf.flights:
        if not fl.is_free:
            warnings.append(f"flight {fl.index} ({fl.t_start_s:.4f}..{fl.t_end_s:.4f} s) is not a free flight: "
                            f"{fl.reason}; no COR from it")
    return warnings + sf.rejected


# ------------------------------------------------------------------ impacts without a COR
def landing_pass(sf: StreamingFitter, hops: HopPass, *, levels: dict, track: DicTrack, structure: StructureFit,
                 config: SegmentationConfig) -> tuple[list[Landing], list[str]]:
    """Impacts without a COR (:mod:`vibro_fit.landings`, plus where each chain's last hop lands), in time
    order, with one warning each."""
    hop_ids = {id(h) for c in hops.chains for h in c.hops}
    landings = find_landings([f for f in hops.flights if id(f) not in hop_ids], hops.impacts,
                             clusters=sf.clusters, short_flights=sf.short_flights, structure=structure,
                             plate_levels=levels, track=track, max_impact_frames=config.max_impact_frames)
    for c in hops.chains:   # where the last measured hop lands: the chatter after it is too short to fit
        if c.landing_s is not None and c.hops:
            landings.append(Landing(c.landing_s, c.plate, float(c.landing_v_rel_mps), int(c.hops[-1].index),
                                    "the last hop measured on the plate lands here; the rebound after it lasts "
                                    "too few frames to fit a flight (chatter, then the ball rides the plate: "
                                    "contact phase)"))
    landings.sort(key=lambda x: x.t_s)
    warnings = [f"impact without COR at t = {ld.t_s:.4f} s on the {ld.plate} plate (relative speed "
                f"{abs(ld.v_rel_before_mps):.3f} m/s, end of flight {ld.flight_before}): {ld.reason}"
                for ld in landings]
    return landings, warnings


def unseen_pass(acc: AccelPass, hops: HopPass, landings: list[Landing], track: DicTrack,
                fps: float) -> tuple[list[float] | None, list[str]]:
    """Accelerometer impacts (camera clock, s) the camera does not identify (None without accelerometers or
    a determined offset), and the warning saying so or saying why they cannot be located."""
    if acc.analysis is None:
        return None, []
    impacts = hops.impacts
    unseen = _accel_unseen(acc.camera_times_s, impacts, landings, hops.flights, track.t_s, fps)
    n_acc = len(acc.analysis.impacts)
    if unseen:
        return unseen, [f"the accelerometers see {len(unseen)} impact(s) the camera does not identify, at t = "
                        + ", ".join(f"{x:.4f}" for x in unseen[:10]) + (" ..." if len(unseen) > 10 else "")
                        + " s (camera clock): they were used as impact-time hints for the segmentation"]
    if acc.camera_times_s is None and n_acc > len(impacts) + len(landings):
        return unseen, [f"the accelerometers detect {n_acc} impacts, the camera {len(impacts)} with a COR and "
                        f"{len(landings)} without: with the clock offset not determined they cannot be paired, "
                        "so the impacts only the accelerometers see are not located on the camera clock"]
    return unseen, []


def _accel_unseen(accel_cam_s, impacts, landings, flights, t, fps: float) -> list[float] | None:
    """Accelerometer impacts (camera clock) with no DIC impact or landing within 1.5 frame intervals, between
    the first fitted flight's start and the last one's end (an impact before the first flight or after the
    last one has no flight on one side: the camera cannot identify it); None when the clock offset is
    unknown."""
    if accel_cam_s is None:
        return None
    seen = np.sort(np.array([i.t_s for i in impacts] + [x.t_s for x in landings], float))
    lo, hi = float(t[0]), float(t[-1])
    if flights:
        lo, hi = min(f.t_start_s for f in flights), max(f.t_end_s for f in flights)
    tol = 1.5 / fps
    out = []
    for x in accel_cam_s:
        if not (lo <= x <= hi):
            continue
        if seen.size == 0 or np.min(np.abs(seen - x)) > tol:
            out.append(float(x))
    return out


# ------------------------------------------------------------------ regime, motion state, rig consistency
def regime_pass(sf: StreamingFitter, hops: HopPass, *, n_landings: int, track: DicTrack, basis: MotionBasis,
                rig: RigConfig, config: SegmentationConfig) -> tuple[Regime, list[str]]:
    """The motion regime (:mod:`vibro_fit.regimes`) and, unless it is two impacts per cycle, its warning."""
    t = track.t_s
    dt = float(np.median(np.diff(t)))
    regime = classify_regime(RegimeEvidence(
        duration_s=float(t[-1] - t[0] + dt), frequency_hz=basis.f_motion_hz, impacts=hops.impacts,
        clusters=sf.clusters, short_flights=sf.short_flights, max_impact_frames=config.max_impact_frames,
        frame_dt_s=dt, y_rel_range_mm=y_rel_range(track.ball_mm, track.structure_mm),
        free_play_mm=rig.free_play_mm, n_landings=n_landings, contacts=hops.contacts,
        n_hop_impacts=sum(len(c.impacts) for c in hops.chains)))
    if regime.name != "two_impacts_per_cycle":
        return regime, [f"regime: {regime.name} ({'; '.join(regime.notes) or 'see regime counts'})"]
    return regime, []


def motion_pass(sf: StreamingFitter, hops: HopPass, n_landings: int, track: DicTrack,
                basis: MotionBasis) -> tuple[MotionState, list[str]]:
    """What the recording shows (still, structure only, ball moving, impacting) and, unless impacting, why."""
    motion = classify_motion(basis.structure, y_rel_range(track.ball_mm, track.structure_mm), float(basis.noise_mm),
                             sum(1 for f in sf.flights if f.is_free), len(hops.impacts), n_landings,
                             structure_noise_mm=basis.structure_noise_mm)
    return motion, ([motion.message()] if motion.state != "impacting" else [])


def rig_pass(rig: RigConfig, accel: AccelData | None, sf: StreamingFitter, impacts: list[ImpactFit],
             basis: MotionBasis, g_mps2: float) -> tuple[list[RigStatement], list[str]]:
    """Contradictions between rig.yaml and the measurement (:mod:`vibro_fit.rig_consistency`), one warning
    each."""
    moving = basis.moving
    daq_f = excitation_on_daq_clock_hz(accel, rig.excitation.frequency_hz) if accel is not None and moving else None
    rig_state = check_rig(rig, basis.structure, moving, impacts, sf.flights, float(basis.noise_mm), g_mps2,
                          daq_frequency_hz=daq_f)
    return rig_state, [f"rig description inconsistent with the measurement: {r.message}" for r in rig_state]
