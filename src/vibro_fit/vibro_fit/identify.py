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
from .contacts import ContactPhase, contact_frames, find_contacts, refine_contacts
from .coverage import FrameCoverage, frame_coverage
from .flight_fit import FlightFit
from .gaps import GapVerdict
from .hops import HopChain, acceleration_prior, hop_chain
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

SHORT_FLIGHT_POINTS = 6   # a flight opened by a COR impact with fewer than twice this joins the hop chain after it


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
    contacts: list[ContactPhase] = field(default_factory=list)   # the ball riding a plate (vibro_fit.contacts)
    hop_chains: list[HopChain] = field(default_factory=list)     # short hops measured on the plate (vibro_fit.hops)

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
                  free_play_mm: float | None = None, contact_frames: set[int] | None = None) -> StreamingFitter:
    """Run the streaming fitter over a whole track (accelerometer impact times on the camera clock;
    ``free_play_mm``: the rig's, for impacts inside lost frames, :mod:`vibro_fit.gaps`; ``contact_frames``:
    track indices of the ball riding a plate, :mod:`vibro_fit.contacts`)."""
    sf = StreamingFitter(frequency_hz, noise_mm=noise_mm, method="paper" if method == "joint" else method,
                         config=config, weights=weights, free_play_mm=free_play_mm, contact_frames=contact_frames)
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

    Parameters
    ----------
    track : DicTrack
        The DIC track: times (s), ball and structure displacements (mm, + up), lost frames flagged.
    rig : RigConfig
        rig.yaml: the excitation's nominal frequency (Hz), ball and cavity geometry (mm).
    accel : AccelData, optional
        Accelerometer samples (s on the DAQ clock, m/s^2). The impacts are then also detected on them, the
        camera-to-DAQ clock offset estimated, and the accelerometer impact times (camera clock) used to refine
        the segmentation; the offset is used only when determined (see
        :func:`~vibro_fit.accel_impacts.estimate_clock_offset`), else the reason is a warning.
    method : str
        ``"paper"`` (Eq. 15-16 on separate parabola fits) or ``"joint"`` (pairs of flights refitted with the
        constraint that they meet on the plate).
    config : SegmentationConfig, optional
        Thresholds of the flight segmentation (default: :class:`SegmentationConfig`'s).
    highpass_hz : float
        Corner of the accelerometers' high-pass filter (Hz).
    weights : str, optional
        ``"dic_valid"``: the flight fits weighted by the number of valid ball mesh points of each frame.

    Returns
    -------
    Identification
        Structure sine (mm, Hz, rad), flights (parabola coefficients, mm and s), impacts (time s, velocities
        m/s, COR with sigmas), friction, regime, contacts, gaps and warnings.

    Raises
    ------
    RecordingError
        An unknown ``method`` or ``weights``; a track of fewer than 20 frames or 20 usable ones, or whose times
        do not increase.

    Notes
    -----
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
    sig_rel = float(np.hypot(noise, structure.rms_residual_mm))
    levels0 = {k: v for k, v in plate_levels(list(sf.impacts)).items() if k in ("top", "bottom")}
    contacts = find_contacts(t, ball, st, good, sig_rel, rig.free_play_mm, levels0)
    cframes = contact_frames(contacts, good)
    if cframes:
        # the ball riding a plate: contact frames whatever their acceleration (near release it is -g)
        sf = run_streaming(track, f_nom, noise, method, cfg, accel_times_s=accel_cam_s or (), weights=weights,
                           free_play_mm=rig.free_play_mm, contact_frames=cframes)
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
    chains = _hop_chains(sf, impacts, levels, contacts, cframes, track, rig, f_motion, float(noise))
    flights = list(sf.flights)
    if chains:
        flights, impacts = _merge_chains(flights, impacts, chains, sf.gaps)
    if contacts:
        prior = acceleration_prior(sf.flights)
        contacts = refine_contacts(contacts, chains, structure, 2.0e-3 * prior[0] if prior else None,
                                   1.0 / rig.camera.fps)
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
    hop_ids = {id(h) for c in chains for h in c.hops}
    landings = find_landings([f for f in flights if id(f) not in hop_ids], impacts, sf.clusters, sf.short_flights,
                             structure, levels, t, ball, st, cfg.max_impact_frames)
    for c in chains:   # where the last measured hop lands: the chatter after it is too short to fit
        if c.landing_s is not None and c.hops:
            landings.append(Landing(c.landing_s, c.plate, float(c.landing_v_rel_mps), int(c.hops[-1].index),
                                    "the last hop measured on the plate lands here; the rebound after it lasts "
                                    "too few frames to fit a flight (chatter, then the ball rides the plate: "
                                    "contact phase)"))
    landings.sort(key=lambda x: x.t_s)
    for ld in landings:
        warnings.append(f"impact without COR at t = {ld.t_s:.4f} s on the {ld.plate} plate (relative speed "
                        f"{abs(ld.v_rel_before_mps):.3f} m/s, end of flight {ld.flight_before}): {ld.reason}")
    unseen = None
    if accel_res is not None:
        unseen = _accel_unseen(accel_cam_s, impacts, landings, flights, t, rig.camera.fps)
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
                             n_landings=len(landings), contacts=contacts,
                             n_hop_impacts=sum(len(c.impacts) for c in chains))
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
    return Identification(structure=structure, flights=flights, impacts=impacts, friction=friction,
                          cor_summary=cor_summary(impacts), regime=regime, plate_levels=levels,
                          noise_mm=float(noise), method=method, mass_kg=rig.ball.mass_kg,
                          short_flights=list(sf.short_flights), clusters=list(sf.clusters),
                          accel=accel_res, clock_offset=offset, warnings=warnings, weights=weights or "none",
                          coverage=coverage, motion=motion, landings=landings, accel_unseen_s=unseen,
                          rig_consistency=rig_state, gaps=list(sf.gaps), contacts=contacts, hop_chains=chains)


def _hop_chains(sf: StreamingFitter, impacts: list[ImpactFit], levels: dict, contacts: list[ContactPhase],
                cframes: set[int], track: DicTrack, rig: RigConfig, f_hz: float, noise_mm: float) -> list[HopChain]:
    """The short hops after every free flight that no COR impact closes (:mod:`vibro_fit.hops`): the plate's
    level from the impacts, else from its contact phases; hops stop before a contact phase or the next
    fitted flight."""
    from .structure_fit import fit_structure

    prior = acceleration_prior(sf.flights)
    if prior is None:
        return []
    lv = {p: levels[p] for p in ("top", "bottom") if p in levels}
    for plate in ("top", "bottom"):
        vals = [c.level_mm for c in contacts if c.plate == plate]
        if plate not in lv and vals:
            lv[plate] = float(np.median(vals))
    t, ball, st, good = track.t_s, track.ball_mm, track.structure_mm, track.good
    usable = good.copy()
    if cframes:
        usable[np.fromiter(cframes, int)] = False
    dt = float(np.median(np.diff(t)))
    closed = {i.flight_before for i in impacts}
    by_index = {f.index: f for f in sf.flights}
    fitted = sorted([f for f in sf.flights if f.fitted], key=lambda f: f.t_start_s)
    chains: list[HopChain] = []
    n_imp, n_fl = 10 ** 6, 10 ** 6   # temporary indices, renumbered by _merge_chains
    for k, fl in enumerate(fitted):
        if not fl.is_free or fl.index in closed:
            continue
        t_lim = float(t[-1]) + dt
        if k + 1 < len(fitted):
            t_lim = min(t_lim, fitted[k + 1].t_start_s)
        later = [c.start_s for c in contacts if c.start_s > fl.t_end_s]
        if later:
            t_lim = min(t_lim, later[0])
        w = (t >= fl.t_start_s - 1.0 / f_hz) & (t <= t_lim) & good
        if w.sum() < 8:
            continue
        s_fit = fit_structure(t[w], st[w], f0_hz=f_hz)
        v_end = float(fl.velocity_mps(fl.t_end_s) - s_fit.velocity_mps(fl.t_end_s))
        plate = "bottom" if v_end < 0 else "top"
        if plate not in lv:
            continue
        # a short flight opened by a COR impact on the same plate is the chain's first hop: the chain starts
        # from the flight before it (its launch then sits on the plate's level, and its sigma is the chain's)
        start, replaced = fl, None
        opened = next((i for i in impacts if i.flight_after == fl.index), None)
        prev = by_index.get(opened.flight_before) if opened is not None else None
        if opened is not None and opened.plate == plate and fl.n_points < 2 * SHORT_FLIGHT_POINTS \
                and prev is not None and prev.is_free:
            start, replaced = prev, (opened, fl)
            w = (t >= prev.t_start_s - 1.0 / f_hz) & (t <= t_lim) & good
            s_fit = fit_structure(t[w], st[w], f0_hz=f_hz)
        ch = hop_chain(start, plate, lv[plate], s_fit, t, ball, usable, t_lim, prior, noise_mm, n_imp, n_fl)
        if ch is None and replaced is not None:
            ch = hop_chain(fl, plate, lv[plate], s_fit, t, ball, usable, t_lim, prior, noise_mm, n_imp, n_fl)
            replaced = None
        if ch is not None:
            ch.replaces = replaced
            chains.append(ch)
            n_imp += len(ch.impacts)
            n_fl += len(ch.hops)
    return chains


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
