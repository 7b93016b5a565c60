"""Whole-recording identification: structure, flights, impacts, friction, COR summary, regime, clock offset.

The per-impact path is :class:`vibro_fit.streaming.StreamingFitter` run over the whole track (so the
offline result and the node's streamed estimates are the same numbers); the global structure fit,
statistics, regime, accelerometer analysis and the ``joint`` refinement are added here.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from vibro_io.accel import AccelData
from vibro_io.dictrack import DicTrack, FrameTrack
from vibro_io.rig import RigConfig
from vibro_model.errors import RecordingError
from vibro_model.results import StructureMotion

from .accel_impacts import AccelAnalysis, ClockOffset, analyse_accel, estimate_clock_offset
from .coverage import FrameCoverage, frame_coverage
from .flight_fit import FlightFit
from .gaps import GapVerdict
from .impacts import ImpactFit, joint_impact
from .landings import Landing, find_landings
from .methods import METHODS
from .motion_state import MotionState, classify_motion, structure_moves
from .regimes import Regime, classify_regime, y_rel_range
from .rig_consistency import RigStatement, check_rig, excitation_on_daq_clock_hz
from .segmentation import SegmentationConfig, noise_sigma_mm, plate_levels
from .statistics import cor_summary
from .streaming import Cluster, StreamingFitter
from .structure_fit import StructureFit, fit_structure

log = logging.getLogger(__name__)


@dataclass(kw_only=True)
class Identification:
    """Everything identified from one recording (positions mm, velocities m/s, forces N, times s)."""

    structure: StructureFit
    flights: list[FlightFit]
    impacts: list[ImpactFit]
    friction: list[dict]
    cor_summary: dict
    regime: Regime
    plate_levels: dict
    noise_mm: float
    method: str
    mass_kg: float
    short_flights: list[FlightFit] = field(default_factory=list)
    clusters: list[Cluster] = field(default_factory=list)
    accel: AccelAnalysis | None = None
    clock_offset: ClockOffset | None = None
    warnings: list[str] = field(default_factory=list)
    weights: str = "none"
    coverage: FrameCoverage | None = None  # filmed interval vs accelerometer record (with accel only)
    motion: MotionState | None = None      # still / structure only / ball moving / impacting
    landings: list[Landing] = field(default_factory=list)   # impacts without a COR (short rebound, chatter)
    accel_unseen_s: list[float] | None = None  # accelerometer impacts (camera clock) the camera does not see
    rig_consistency: list[RigStatement] = field(default_factory=list)
    gaps: list[GapVerdict] = field(default_factory=list)   # runs of lost frames: impact found, or what they may hide

    def structure_motion(self) -> StructureMotion:
        """The identified structure as the model type, with the ball offset from the plate levels; no
        frequency or phase when the structure did not move beyond DIC noise."""
        moves = self.motion.structure_moves if self.motion is not None else True
        return self.structure.motion(self.plate_levels.get("offset_mm", 0.0), moves)

    @property
    def rig_consistent(self) -> bool:
        """False when a rig.yaml inconsistency forbids building physics findings on this identification."""
        return not any(r.blocks_physics for r in self.rig_consistency)


def track_rows(track: DicTrack):
    """The FrameTrack rows of a DicTrack, in order."""
    for k in range(len(track)):
        yield FrameTrack(frame=int(track.frame[k]), t_s=float(track.t_s[k]), ball_mm=float(track.ball_mm[k]),
                         structure_mm=float(track.structure_mm[k]), ball_valid=int(track.ball_valid[k]),
                         structure_valid=int(track.structure_valid[k]),
                         ball_zncc=float(track.ball_zncc[k]), structure_zncc=float(track.structure_zncc[k]),
                         lost=bool(track.lost[k]))


def run_streaming(track: DicTrack, frequency_hz: float, noise_mm: float | None, method: str = "paper",
                  config: SegmentationConfig | None = None, accel_times_s=(), weights: str | None = None,
                  free_play_mm: float | None = None) -> StreamingFitter:
    """Run the streaming fitter over a whole track (accelerometer impact times on the camera clock;
    ``free_play_mm``: the rig's, for impacts inside lost frames, :mod:`vibro_fit.gaps`)."""
    sf = StreamingFitter(frequency_hz, noise_mm=noise_mm, method="paper" if method == "joint" else method,
                         config=config, weights=weights, free_play_mm=free_play_mm)
    for tx in accel_times_s:
        sf.push_accel_impact(tx)
    for row in track_rows(track):
        sf.push(row)
    sf.finish()
    return sf


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


def _validate(track: DicTrack) -> None:
    n = len(track)
    if n < 20:
        raise RecordingError(f"DIC track: {n} frames, need at least 20 to identify the motion")
    if np.any(np.diff(track.t_s) <= 0):
        k = int(np.flatnonzero(np.diff(track.t_s) <= 0)[0]) + 1
        raise RecordingError(f"DIC track: frame {int(track.frame[k])}: time {track.t_s[k]} s does not increase")
    good = track.good
    if good.sum() < 20:
        raise RecordingError(f"DIC track: only {int(good.sum())} of {n} frames are usable (not lost, finite)")


def identify(track: DicTrack, rig: RigConfig, accel: AccelData | None = None, method: str = "paper",
             config: SegmentationConfig | None = None, highpass_hz: float = 100.0,
             weights: str | None = None) -> Identification:
    """Identify structure motion, free flights, impacts (COR), friction and regime from a DIC track.

    ``method``: "paper" (Eq. 15-16 on separate parabola fits) or "joint" (pairs of flights refitted with the
    constraint that they meet on the plate). With ``accel`` the impacts are also detected on the
    accelerometers, the camera-to-DAQ clock offset estimated, and the accelerometer impact times (camera
    clock) used to refine the segmentation; the offset is used only when determined (see
    :func:`~vibro_fit.accel_impacts.estimate_clock_offset`), else the reason is a warning.
    ``weights="dic_valid"`` weights the flight fits by the number of valid ball mesh points of each frame.

    Also stated (warnings and fields): what the recording shows (``motion``), impacts without a COR
    (``landings``), accelerometer impacts the camera misses (``accel_unseen_s``) and contradictions between
    rig.yaml and the measurement (``rig_consistency``).
    """
    if weights not in (None, "none", "dic_valid"):
        raise RecordingError(f"identify: unknown weights {weights!r} (none, dic_valid)")
    if method not in METHODS:
        raise RecordingError(f"identify: unknown method {method!r} (choose from {', '.join(METHODS)})")
    _validate(track)
    cfg = config or SegmentationConfig()
    warnings: list[str] = []
    good = track.good
    t, ball, st = track.t_s, track.ball_mm, track.structure_mm
    f_nom = rig.excitation.frequency_hz
    structure = fit_structure(t[good], st[good])
    moving = structure_moves(structure.amplitude_mm, float(structure.std[0]), structure.rms_residual_mm)
    f_motion = structure.frequency_hz if moving else f_nom
    if moving and abs(structure.frequency_hz - f_nom) > 0.05 * f_nom:
        warnings.append(f"structure frequency {structure.frequency_hz:.3f} Hz differs from the nominal "
                        f"{f_nom:g} Hz (rig.yaml excitation.frequency_hz) by more than 5 %")
    if good.sum() < len(track):
        warnings.append(f"{int(len(track) - good.sum())} lost/invalid frames excluded")
    noise = noise_sigma_mm(t[good], ball[good])
    if not np.isfinite(noise):
        noise = 0.0
    sf = run_streaming(track, f_nom, noise, method, cfg, weights=weights, free_play_mm=rig.free_play_mm)
    accel_res = None
    offset = None
    coverage = None
    accel_cam_s: list[float] | None = None
    if accel is not None:
        accel_res = analyse_accel(accel, f_motion, highpass_hz=highpass_hz)
        warnings += accel_res.warnings
        acc_t = [i.t_s for i in accel_res.impacts]
        offset = _clock_offset(acc_t, sf, structure, rig, track, cfg, f_motion, accel)
        if offset is not None and offset.determined:
            accel_cam_s = [x - offset.offset_s for x in acc_t]
            sf = run_streaming(track, f_nom, noise, method, cfg, accel_times_s=accel_cam_s, weights=weights,
                               free_play_mm=rig.free_play_mm)
        elif acc_t:
            why = offset.reason if offset is not None else "no accelerometer impact lies within 1 s of a DIC impact"
            durations = (f"; the accelerometer record lasts {float(accel.t_s[-1] - accel.t_s[0]):.3f} s, "
                         f"the video {float(t[-1] - t[0]):.3f} s")
            warnings.append(f"clock offset unknown: not determined ({why}{durations}); accelerometer impacts are "
                            "not paired with the camera's, segmentation from DIC only")
        coverage = frame_coverage(t, accel.t_s, acc_t, offset.known_offset_s if offset is not None else None,
                                  1.0 / rig.camera.fps)
        if coverage.message():
            warnings.append(coverage.message())
    impacts = list(sf.impacts)
    levels = plate_levels(impacts, rig.free_play_mm)
    if method == "joint":
        by_index = {f.index: f for f in sf.flights}
        priors = acceleration_priors(sf.flights)
        refined = []
        for est in impacts:
            y_plate = levels.get(est.plate) if est.plate in ("top", "bottom") else None
            p, q = by_index.get(est.flight_before), by_index.get(est.flight_after)
            if y_plate is None or p is None or q is None:
                refined.append(est)
                continue
            refined.append(joint_impact(est, p, q, t, ball, y_plate,
                                        (_prior_for(p, priors), _prior_for(q, priors)), noise))
        impacts = refined
    b = rig.free_play_mm
    if "free_play_mm" in levels and abs(levels["free_play_mm"] - b) > 0.05 * b:
        warnings.append(f"measured free play {levels['free_play_mm']:.3f} mm (half the ball's relative travel "
                        f"between the plates) differs from rig.yaml (gap - diameter)/2 = {b:.3f} mm by more than 5 %")
    friction = []
    for fl in sf.flights:
        if not fl.direction:
            # no impact next to it: the sign of the relative velocity (ball - structure) at mid-flight
            tm = 0.5 * (fl.t_start_s + fl.t_end_s)
            fl.direction = "up" if fl.velocity_mps(tm) - structure.velocity_mps(tm) > 0 else "down"
        f_n, f_std = fl.friction_n(rig.ball.mass_kg, cfg.g_mps2)
        friction.append({"flight": fl.index, "friction_n": f_n, "friction_std_n": f_std,
                         "direction": fl.direction, "free": fl.is_free})
    for fl in sf.flights:
        if not fl.is_free:
            warnings.append(f"flight {fl.index} ({fl.t_start_s:.4f}..{fl.t_end_s:.4f} s) is not a free flight: "
                            f"{fl.reason}; no COR from it")
    warnings += sf.rejected
    landings = _landings(sf, structure, rig, t, ball, st, cfg, levels)
    for ld in landings:
        warnings.append(f"impact without COR at t = {ld.t_s:.4f} s on the {ld.plate} plate (relative speed "
                        f"{abs(ld.v_rel_before_mps):.3f} m/s, end of flight {ld.flight_before}): {ld.reason}")
    unseen = None
    if accel_res is not None:
        unseen = _accel_unseen(accel_cam_s, impacts, landings, sf.flights, t, rig.camera.fps)
        n_acc = len(accel_res.impacts)
        if unseen:
            warnings.append(f"the accelerometers see {len(unseen)} impact(s) the camera does not identify, at t = "
                            + ", ".join(f"{x:.4f}" for x in unseen[:10]) + (" ..." if len(unseen) > 10 else "")
                            + " s (camera clock): they were used as impact-time hints for the segmentation")
        elif accel_cam_s is None and n_acc > len(impacts) + len(landings):
            warnings.append(f"the accelerometers detect {n_acc} impacts, the camera {len(impacts)} with a COR and "
                            f"{len(landings)} without: with the clock offset not determined they cannot be paired, "
                            "so the impacts only the accelerometers see are not located on the camera clock")
    dt = float(np.median(np.diff(t)))
    regime = classify_regime(float(t[-1] - t[0] + dt), f_motion, impacts, sf.clusters,
                             sf.short_flights, cfg.max_impact_frames, dt, y_rel_range(ball, st), b,
                             n_landings=len(landings))
    if regime.name != "two_impacts_per_cycle":
        warnings.append(f"regime: {regime.name} ({'; '.join(regime.notes) or 'see regime counts'})")
    motion = classify_motion(structure, y_rel_range(ball, st), float(noise),
                             sum(1 for f in sf.flights if f.is_free), len(impacts), len(landings))
    if motion.state != "impacting":
        warnings.append(motion.message())
    daq_f = excitation_on_daq_clock_hz(accel, f_nom) if accel is not None and moving else None
    rig_state = check_rig(rig, structure, moving, impacts, sf.flights, float(noise), cfg.g_mps2, daq_f)
    for r in rig_state:
        warnings.append(f"rig description inconsistent with the measurement: {r.message}")
    return Identification(structure=structure, flights=list(sf.flights), impacts=impacts, friction=friction,
                          cor_summary=cor_summary(impacts), regime=regime, plate_levels=levels,
                          noise_mm=float(noise), method=method, mass_kg=rig.ball.mass_kg,
                          short_flights=list(sf.short_flights), clusters=list(sf.clusters),
                          accel=accel_res, clock_offset=offset, warnings=warnings, weights=weights or "none",
                          coverage=coverage, motion=motion, landings=landings, accel_unseen_s=unseen,
                          rig_consistency=rig_state, gaps=list(sf.gaps))


def _clock_offset(acc_t: list[float], sf: StreamingFitter, structure: StructureFit, rig: RigConfig,
                  track: DicTrack, cfg: SegmentationConfig, f_motion_hz: float, accel: AccelData
                  ) -> ClockOffset | None:
    """Camera-to-DAQ offset from the COR impacts; when that is not determined, from the COR impacts plus the
    landings (impacts without a COR, located to a frame or better: tolerance 0.5 ms + half a frame)."""
    t = track.t_s
    spans = {"accel_span_s": (float(accel.t_s[0]), float(accel.t_s[-1])),
             "camera_span_s": (float(t[0]), float(t[-1]))}
    offset = estimate_clock_offset(acc_t, [i.t_s for i in sf.impacts], period_s=1.0 / f_motion_hz, **spans)
    if offset is not None and offset.determined:
        return offset
    marks = sorted([i.t_s for i in sf.impacts]
                   + [x.t_s for x in _landings(sf, structure, rig, t, track.ball_mm, track.structure_mm, cfg)])
    alt = estimate_clock_offset(acc_t, marks, period_s=1.0 / f_motion_hz, tol_s=0.0005 + 0.5 / rig.camera.fps,
                                **spans)
    if alt is not None and (alt.determined or offset is None or alt.n_matched > offset.n_matched):
        return alt
    return offset


def _landings(sf: StreamingFitter, structure: StructureFit, rig: RigConfig, t, ball, st,
              cfg: SegmentationConfig, levels: dict | None = None) -> list[Landing]:
    """Impacts without a COR of a streaming run (see :mod:`vibro_fit.landings`)."""
    if levels is None:
        levels = plate_levels(list(sf.impacts), rig.free_play_mm)
    return find_landings(sf.flights, sf.impacts, sf.clusters, sf.short_flights, structure, levels, t, ball, st,
                         cfg.max_impact_frames)


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
