"""Whole-recording identification: structure, flights, impacts, friction, COR summary, regime, clock offset.

The per-impact path is :class:`vibro_fit.streaming.StreamingFitter` run over the whole track (so the
offline result and the node's streamed estimates are the same numbers); the global structure fit,
statistics, regime, accelerometer analysis and the ``joint`` refinement are added here.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from vibro_io.accel import AccelData
from vibro_io.dictrack import DicTrack
from vibro_io.rig import RigConfig
from vibro_model.constants import G_MPS2
from vibro_model.results import StructureMotion

from .accel_impacts import AccelAnalysis, ClockOffset
from .contacts import ContactPhase
from .coverage import FrameCoverage
from .drive import DriveModel
from .drive_velocity import drive_velocity_pass
from .flight_fit import FlightFit
from .gaps import GapVerdict
from .hops import HopChain
from .impacts import ImpactFit
from .landings import Landing
from .methods import METHODS
from .model_error import noise_floor_pass, widened_pass
from .motion_state import MotionState
from .passes import (
    StreamingSettings,
    accel_pass,
    contact_pass,
    drive_pass,
    flight_warnings,
    friction_pass,
    hop_pass,
    impact_pass,
    landing_pass,
    motion_pass,
    regime_pass,
    rig_pass,
    run_streaming,
    structure_pass,
    track_rows,
    unseen_pass,
    validate_inputs,
)
from .plate_motion import PlateMotion, plate_motion_notes, plate_motion_pass
from .regimes import Regime
from .rig_consistency import RigStatement
from .segmentation import SegmentationConfig, segmentation_config
from .statistics import cor_summary
from .streaming import Cluster
from .structure_fit import StructureFit
from .subpixel_bias import SubpixelBias, subpixel_bias

__all__ = ["METHODS", "Identification", "identify", "track_rows"]

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
    g_axis_mps2: float = G_MPS2     # gravity along the motion axis as mounted, g cos(setup.axis_tilt_deg)
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
    drive: DriveModel | None = None    # the drive in windows, stationary or not (vibro_fit.drive); None: no motion
    dic_bias: SubpixelBias | None = None   # DIC's sub-pixel bias, measured and taken out (vibro_fit.subpixel_bias)
    plate_motion: dict[str, PlateMotion] = field(default_factory=dict)   # each plate against the structure

    def corrected_track(self, track: DicTrack) -> DicTrack:
        """``track`` as this identification measured it: with the sub-pixel bias it took out (:attr:`dic_bias`)
        taken out. Every later stage (cross-checks, the discrepancy analysis) reads this one."""
        return self.dic_bias.corrected(track) if self.dic_bias is not None else track

    def structure_motion(self) -> StructureMotion:
        """The identified structure as the model type, with the ball offset from the plate levels; no
        frequency or phase when the structure did not move beyond DIC noise."""
        moves = self.motion.structure_moves if self.motion is not None else True
        return self.structure.motion(self.plate_levels.get("offset_mm", 0.0), moves)

    @property
    def rig_consistent(self) -> bool:
        """False when a rig.yaml inconsistency forbids building physics findings on this identification."""
        return not any(r.blocks_physics for r in self.rig_consistency)


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
        Thresholds of the flight segmentation (default: :class:`SegmentationConfig`'s); its gravity along the
        axis is always the rig's, g cos(setup.axis_tilt_deg) (:func:`~vibro_fit.segmentation.segmentation_config`).
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

    The passes (:mod:`vibro_fit.passes`) run in this order: validate, structure, drive (stationary or not:
    :mod:`vibro_fit.drive`), streaming fitter, accelerometers and clock offset, contact phases, impacts
    (``joint`` refinement), hop chains, the COR sigmas' floors (:mod:`vibro_fit.model_error`), the structure's
    velocity at each impact under a drive that is not stationary (:mod:`vibro_fit.drive_velocity`), each plate's motion
    against the tracked structure (:mod:`vibro_fit.plate_motion`: a creeping plate's velocity taken into its
    CORs), friction, landings, unseen accelerometer impacts, regime, motion state,
    rig consistency. The streaming fitter runs once, plus once
    more for each of two inputs it can only take from the start of the track, as it segments frame by frame:

    1. always, from the DIC alone: its impacts give the clock offset and the plate levels;
    2. again when the clock offset is determined, with the accelerometer impact times (camera clock) as hints;
       it needs the offset, which needs the impacts of run 1;
    3. again when contact phases are found, with their frames (and the hints of run 2); the contact phases
       are found with the plate levels of the run before, so this cannot be merged into run 2.

    Every later pass reads the last run.

    Then DIC's sub-pixel bias (:mod:`vibro_fit.subpixel_bias`) is measured on the track against this
    identification's structure and free flights; where it is taken out of a body's track, every pass runs again
    on the corrected track but the accelerometers' impact detection, which the track does not enter
    (:attr:`Identification.dic_bias` says what was found and done; :meth:`Identification.corrected_track` gives
    the track the result was measured on).
    """
    ident = _identify_once(track, rig, accel, method, config, highpass_hz, weights)
    frames = [np.asarray(f.frames, dtype=int) for f in ident.flights if f.is_free and f.frames is not None]
    bias = subpixel_bias(track, frames, ident.structure.frequency_hz, rig.camera.mm_per_px)
    if bias.applied:   # the accelerometers did not change: their impacts are not detected again
        ident = _identify_once(bias.corrected(track), rig, accel, method, config, highpass_hz, weights,
                               accel_analysis=ident.accel)
    ident.dic_bias = bias
    return ident


def _identify_once(track: DicTrack, rig: RigConfig, accel: AccelData | None, method: str,
                   config: SegmentationConfig | None, highpass_hz: float, weights: str | None,
                   accel_analysis: AccelAnalysis | None = None) -> Identification:
    """One run of every pass on ``track`` (:func:`identify`'s passes); ``accel_analysis``: the accelerometers'
    impacts as an earlier run on the same ``accel`` detected them (else detected here)."""
    validate_inputs(track, method, weights)
    cfg = segmentation_config(rig, config)
    basis = structure_pass(track, rig)
    drive, drive_notes = drive_pass(track, basis)
    settings = StreamingSettings(frequency_hz=rig.excitation.frequency_hz, noise_mm=basis.noise_mm, method=method,
                                 config=cfg, weights=weights, free_play_mm=rig.free_play_mm)
    sf = run_streaming(track, settings)
    acc = accel_pass(accel, sf, track=track, rig=rig, basis=basis, config=cfg, highpass_hz=highpass_hz,
                     analysis=accel_analysis)
    if acc.camera_times_s is not None:
        sf = run_streaming(track, settings, accel_times_s=acc.camera_times_s)
    contacts, cframes = contact_pass(track, sf, basis, rig)
    if cframes:   # the ball riding a plate: contact frames whatever their acceleration (near release it is -g)
        sf = run_streaming(track, settings, accel_times_s=acc.camera_times_s or (), contact_frames=cframes)
    impacts, levels = impact_pass(sf, track, rig, method, basis.noise_mm)
    hops = hop_pass(sf, impacts, levels, contacts=contacts, cframes=cframes, track=track, rig=rig, basis=basis)
    hops = widened_pass(noise_floor_pass(hops), track, rig)
    good = track.good
    driven, drive_velocity_notes = drive_velocity_pass(hops.impacts, track.t_s[good], track.structure_mm[good],
                                                       basis.f_motion_hz,
                                                       drive.stationary if drive is not None else None)
    moved, plates = plate_motion_pass(driven, levels_from=list(sf.impacts) if method == "joint" else None)
    hops = replace(hops, impacts=moved)
    plate_notes = plate_motion_notes(plates, method)
    friction = friction_pass(sf.flights, basis.structure, rig.ball.mass_kg, cfg.g_mps2)
    flight_notes = flight_warnings(sf, levels, rig.free_play_mm)
    landings, landing_notes = landing_pass(sf, hops, levels=levels, track=track, structure=basis.structure,
                                           config=cfg)
    unseen, unseen_notes = unseen_pass(acc, hops, landings, track, rig.camera.fps)
    regime, regime_notes = regime_pass(sf, hops, n_landings=len(landings), track=track, basis=basis, rig=rig,
                                       config=cfg)
    motion, motion_notes = motion_pass(sf, hops, len(landings), track, basis)
    rig_state, rig_notes = rig_pass(rig, accel, sf, hops.impacts, basis, cfg.g_mps2)
    warnings = (basis.warnings + drive_notes + drive_velocity_notes + acc.warnings + flight_notes + landing_notes
                + unseen_notes + regime_notes + motion_notes + rig_notes + plate_notes)
    return Identification(structure=basis.structure, flights=hops.flights, impacts=hops.impacts, friction=friction,
                          cor_summary=cor_summary(hops.impacts), regime=regime, plate_levels=levels,
                          noise_mm=float(basis.noise_mm), method=method, mass_kg=rig.ball.mass_kg,
                          g_axis_mps2=cfg.g_mps2,
                          short_flights=list(sf.short_flights), clusters=list(sf.clusters),
                          accel=acc.analysis, clock_offset=acc.offset, warnings=warnings, weights=weights or "none",
                          coverage=acc.coverage, motion=motion, landings=landings, accel_unseen_s=unseen,
                          rig_consistency=rig_state, gaps=list(sf.gaps), contacts=hops.contacts,
                          hop_chains=hops.chains, drive=drive, plate_motion=plates)
