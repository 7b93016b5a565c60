"""``analyze_recording``: DIC -> identification -> simulation (COR and Hertz models) -> results + report.

The same cores as the nodes: vibro_dic.tracker.track_recording (or its chunked form on Dask workers,
vibro_dic.chunked), vibro_fit.identify (which runs the streaming fitter), vibro_sim.replay.simulate_measured
(COR and Hertz models), vibro_sim.deviation (Eq. 18).

Replay of the identified motion (``replay_models``, on the results document's domain-model types, SI):
the structure is the fitted sine (track coordinates, m; a structure that does not move beyond DIC noise
has no sine to replay); the ball starts at the start of the first free flight with that flight's position and
velocity, moved into the cavity frame by the measured offset c0 between ball and cavity centre at frame 0
(from the impacts' relative positions); each impact uses its identified COR (PerImpact, the mean after
the last) and each flight its identified friction force (0 for a flight that is not free). D is computed
on the measured ball displacement as DIC gives it (since frame 0).
"""

from __future__ import annotations

import logging
import sys
from contextvars import ContextVar
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from vibro_app.cmd_track import DIC_CSV
from vibro_app.report_files import FIGURE_FILES, REPORT_HTML, vector_twin, with_vector_twins
from vibro_app.report_provenance import provenance_section
from vibro_dic.chunked import track_rows
from vibro_dic.quality import TrackQuality, dic_quality_section
from vibro_dic.texture import DEFAULT_MAX_SUBSET_SIGMA_PX
from vibro_dic.tracker import DEFAULT_TRACKING, RESEED_EVERY_FRAMES
from vibro_fit.cross_checks import consistency_checks, consistency_section
from vibro_fit.plausibility import consistency_stage
from vibro_fit.segmentation import SegmentationConfig
from vibro_fit.spin import ball_spin_section
from vibro_io.dictrack import DicTrack, read_dic_csv, write_dic_csv
from vibro_io.frames import find_frames_source
from vibro_io.outputs import atomic_path, prepare_output_dir
from vibro_io.recording import load_recording_accel, open_recording
from vibro_io.results_file import CSV_TABLES, RESULTS_JSON, write_result_tables, write_results
from vibro_io.rig import RigConfig, load_rig
from vibro_model.assemble import (
    BallSpinStage,
    DicQualityStage,
    DiscrepancyStage,
    SimulationStage,
    StageOutputs,
    assemble_results,
)
from vibro_model.drive_envelope import DriveEnvelope
from vibro_model.errors import RecordingError
from vibro_model.results import ResultsDocument, Simulation
from vibro_model.units import m_to_mm, mm_to_m
from vibro_sim.params import BallCavity

log = logging.getLogger(__name__)


def _bar(total: int, progress: bool, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="step", disable=not progress or not sys.stderr.isatty(),
                leave=False, file=sys.stderr)


def replay_models(document, track: DicTrack, rig: RigConfig) -> dict:
    """Simulate the COR and Hertz models with the identified parameters (a results document: structure,
    flights, impacts); D (Eq. 18) of each against the measured ball displacement (track coordinates since
    frame 0). Same core as the simulator node: :mod:`vibro_sim.measured` (SI); mm here only for the figures.
    Where the windowed drive (``drive`` section) found the drive not stationary, the replayed structure follows
    it (:class:`vibro_model.drive_envelope.DriveEnvelope`), as the simulator node's does.

    Returns {"t_s", "measured_mm", "curves": {name: mm}, "deviations": {name: D}, "errors": {name: msg}}.
    """
    from vibro_sim.measured import replay_and_score, replay_inputs

    out = {"t_s": None, "measured_mm": None, "curves": {}, "deviations": {}, "errors": {}}
    good = track.good
    offset_m = document.structure.ball_offset_m or 0.0
    try:
        envelope = DriveEnvelope.of_drive_section(document.sections.get("drive"), document.structure.offset_m or 0.0)
        inputs = replay_inputs(document.structure, document.flights, document.impacts, mm_to_m(rig.free_play_mm),
                               float(track.t_s[good][-1]), offset_m, envelope)
    except ValueError as exc:
        out["errors"]["all"] = str(exc)
        return out
    runs, errors = replay_and_score(inputs, BallCavity.from_rig(rig), track.t_s[good], mm_to_m(track.ball_mm[good]),
                                    offset_m)
    for name, error in errors.items():
        log.warning("%s replay failed: %s", name, error)
    out["errors"].update(errors)
    for name, run in runs.items():
        out["t_s"], out["measured_mm"] = run.t_s, m_to_mm(run.measured_ball_m)
        out["curves"][name] = m_to_mm(run.ball_m)
        out["deviations"][name] = run.deviation
    return out


DISCREPANCY_PNG = "discrepancy.png"


def analyze_outputs() -> tuple[str, ...]:
    """Every file ``vibro analyze`` may write into its output folder (what ``--overwrite`` replaces)."""
    return (RESULTS_JSON, DIC_CSV, *CSV_TABLES, *with_vector_twins((*FIGURE_FILES.values(), DISCREPANCY_PNG)),
            REPORT_HTML)


#: the command line of the ``vibro analyze`` running now (set by :mod:`vibro_app.cmd_analyze`; None from Python)
COMMAND_LINE: ContextVar[tuple[str, ...] | None] = ContextVar("vibro_analyze_command_line", default=None)
#: the identification's flight segmentation and accelerometer high-pass, as every ``vibro analyze`` runs them
SEGMENTATION = SegmentationConfig()
ACCEL_HIGHPASS_HZ = 100.0


def analysis_settings(dic: DicPlan, fit: FitPlan, tracked: bool) -> dict:
    """The options and thresholds an analysis runs with, for results.json's ``provenance.settings``: the DIC's
    (None when a track replaced it) and the identification's."""
    from vibro_fit.streaming import StreamingTuning

    dic_settings = None if not tracked else {
        "tracking": asdict(replace(DEFAULT_TRACKING, method=dic.method)), "reseed_every_frames": RESEED_EVERY_FRAMES,
        "max_subset_sigma_px": DEFAULT_MAX_SUBSET_SIGMA_PX, "workers": dic.workers, "scheduler": dic.scheduler}
    return {"dic": dic_settings,
            "identification": {"method": fit.method, "weights": fit.weights or "none",
                               "segmentation": asdict(SEGMENTATION), "accel_highpass_hz": ACCEL_HIGHPASS_HZ,
                               # None: one nominal drive period (1 / excitation.frequency_hz)
                               "local_structure_history_s": StreamingTuning().history_s}}


@dataclass(frozen=True, kw_only=True)
class DicPlan:
    """How ``vibro analyze`` tracks the frames: the sub-pixel method (``"icgn"`` or ``"parabolic"``,
    :mod:`vibro_dic.tracker`) and where, in this process (no ``workers``, no ``scheduler``), in chunks on a new
    local Dask cluster of ``workers`` processes, or on the Dask scheduler at ``scheduler``
    (:func:`vibro_dic.chunked.track_rows`: the same track either way)."""

    method: str = "icgn"
    workers: int | None = None
    scheduler: str | None = None


@dataclass(frozen=True, kw_only=True)
class FitPlan:
    """How ``vibro analyze`` identifies the motion: the impact method (``"paper"``: Eq. 15-16, or ``"joint"``,
    :func:`vibro_fit.identify.identify`) and the flight-fit weights (None or ``"dic_valid"``: by the valid ball
    subsets per frame)."""

    method: str = "paper"
    weights: str | None = None


def load_inputs(recording_dir: str | Path, track_csv: str | Path | None, *, out_dir: Path, dic: DicPlan,
                progress: bool, overwrite: bool = False, quality=None):
    """(rig, track, accel) from a recording: DIC unless ``track_csv`` is given (then frames are not read).

    DIC runs as ``dic`` plans it (:class:`DicPlan`). The inputs are opened (and validated) before ``out_dir`` is
    prepared (:func:`prepare_output_dir`); with DIC the track is written to ``out_dir/dic.csv`` and ``quality``
    (a :class:`vibro_dic.quality.TrackQuality`, optional) receives the texture check and the correlation
    quality."""
    rec_dir = Path(recording_dir)
    inputs = [rec_dir] + ([Path(track_csv)] if track_csv is not None else [])
    if track_csv is not None:
        if not rec_dir.is_dir():
            raise RecordingError(f"{rec_dir}: not a recording directory")
        rig = load_rig(rec_dir / "rig.yaml")
        track = read_dic_csv(track_csv)
        accel = load_recording_accel(rec_dir, rig)
        prepare_output_dir(out_dir, overwrite=overwrite, owned=analyze_outputs(), command="analyze", inputs=inputs)
        return rig, track, accel

    rec = open_recording(rec_dir)
    accel = rec.load_accel()
    prepare_output_dir(out_dir, overwrite=overwrite, owned=analyze_outputs(), command="analyze", inputs=inputs)
    rows = list(track_rows(rec, workers=dic.workers, scheduler=dic.scheduler, method=dic.method, progress=progress,
                           quality=quality))
    with atomic_path(out_dir / DIC_CSV) as tmp:
        write_dic_csv(tmp, rows)
    return rec.rig, DicTrack.from_frames(rows), accel


def _frames_source_name(recording_dir: str | Path, track_csv: str | Path | None) -> str:
    """How the time-base finding names the frames: the video's file name, or 'the frames'."""
    if track_csv is not None:
        return "the frames"
    try:
        return find_frames_source(recording_dir).name
    except Exception:  # noqa: BLE001 - only a name for a message; the frames were read already
        return "the frames"


class _NoFigure(Exception):
    """The discrepancy run had nothing to plot (its temporary file is discarded)."""


def _write_discrepancy_figure(disc_run, path: Path) -> Path | None:
    from vibro_discrepancy.figures import write_discrepancy_figure

    try:   # the PNG and its vector twin (SVG) beside it, both or neither
        with atomic_path(path) as tmp, atomic_path(vector_twin(path)) as svg:
            if write_discrepancy_figure(disc_run, tmp, svg_path=svg) is None:
                raise _NoFigure
    except _NoFigure:
        return None
    return path


def analyze_recording(recording_dir: str | Path, out_dir: str | Path, *, progress: bool = True,
                      fit: FitPlan = FitPlan(), track_csv: str | Path | None = None, dic: DicPlan = DicPlan(),
                      report: bool = True, overwrite: bool = False) -> dict:
    """Run the whole analysis of one recording (``vibro analyze``).

    Parameters
    ----------
    recording_dir : str or Path
        The recording (rig.yaml beside its frames or camera file, and accelerometer file if any).
    out_dir : str or Path
        Where results.json, flights.csv, impacts.csv, the PNG figures and report.html are written (created;
        refused when it holds anything but this run's inputs, unless ``overwrite``: see
        :func:`vibro_io.outputs.prepare_output_dir`). Every file is written atomically.
    progress : bool
        Progress bars on stderr.
    fit : FitPlan
        The identification's impact method and flight-fit weights.
    track_csv : str or Path, optional
        A DIC track (dic.csv) to use instead of tracking the frames.
    dic : DicPlan
        The DIC's sub-pixel method and where it runs (this process, local workers, a Dask scheduler).
    report : bool
        Write the figures and report.html.
    overwrite : bool
        Replace an earlier analysis's files in ``out_dir``.

    Returns
    -------
    dict
        The results.json document (lengths mm, times s, velocities m/s; docs/recording-format.md).

    Raises
    ------
    RecordingError
        Bad input (named, with where); or a run the cross-checks refuse, after results.json is written with its
        ``consistency`` section and without a COR table.
    """
    from vibro_fit.identify import identify  # scipy: only when an analysis runs

    out = Path(out_dir)
    bar = _bar(4, progress, "analyze")
    try:
        bar.set_description("DIC" if track_csv is None else "read track")
        quality = TrackQuality() if track_csv is None else None
        rig, track, accel = load_inputs(recording_dir, track_csv, out_dir=out, dic=dic, progress=progress,
                                        overwrite=overwrite, quality=quality)
        dic_stage = None if quality is None else _dic_quality_stage(quality)  # refuses a body lost in most frames
        bar.update(1)
        bar.set_description("identify")
        ident = identify(track, rig, accel=accel, method=fit.method, weights=fit.weights, config=SEGMENTATION,
                         highpass_hz=ACCEL_HIGHPASS_HZ)
        track = ident.corrected_track(track)   # every later stage reads the track as identified (dic_bias)
        stages = _checked_identification(ident, track, rig, accel,
                                         recording=str(recording_dir), dic_quality=dic_stage,
                                         frames_name=_frames_source_name(recording_dir, track_csv))
        stages = replace(stages, provenance=provenance_section(
            recording_dir, track_csv, command=COMMAND_LINE.get(),
            settings=analysis_settings(dic, fit, tracked=track_csv is None), rig=rig))
        bar.update(1)
        if stages.consistency.refusal is not None:
            _write_refused(stages, out)
        bar.set_description("simulate")
        stages, sim = _simulated(stages, track, rig)
        bar.update(1)
        bar.set_description("discrepancy")
        stages, disc_run = _with_discrepancy(stages, track, rig)
        document = _with_ball_spin(stages, track)
        write_results(out / RESULTS_JSON, document)
        write_result_tables(document, out)
        if report:
            bar.set_description("report")
            _write_report(document, ident, track, sim, disc_run, out)
        bar.update(1)
    finally:
        bar.close()
    return document.to_dict()


def _dic_quality_stage(quality: TrackQuality) -> DicQualityStage:
    """The DIC's texture and correlation checks as the assembler takes them (refuses a body lost in most
    frames: :meth:`TrackQuality.check`)."""
    dic_warnings = quality.check()
    return DicQualityStage(section=dic_quality_section(quality.texture, quality),
                           warnings=[f"DIC: {w}" for w in quality.texture.warnings() + dic_warnings])


def _checked_identification(ident, track: DicTrack, rig: RigConfig, accel, *, recording: str,
                            dic_quality: DicQualityStage | None, frames_name: str) -> StageOutputs:
    """The stage outputs up to the cross-checks (:func:`vibro_fit.cross_checks.consistency_checks`, the
    trajectory_fitter's core too)."""
    from vibro_fit.results import identified_stage

    findings, evidence = consistency_checks(ident, track, rig, accel, frames_name)
    return StageOutputs(recording=recording, identified=identified_stage(ident), dic_quality=dic_quality,
                        consistency=consistency_stage(findings, consistency_section(findings, evidence)))


def _write_refused(stages: StageOutputs, out: Path) -> None:
    """A run the cross-checks refuse: its document (no COR table, the refusal first among the warnings)
    written, then the refusal raised (exit code 2)."""
    document = assemble_results(stages)
    write_results(out / RESULTS_JSON, document)
    write_result_tables(document, out)
    raise RecordingError(f"{stages.consistency.refusal} (results withheld: {out / RESULTS_JSON} has no COR table, "
                         "see its 'consistency' section)")


def _simulated(stages: StageOutputs, track: DicTrack, rig: RigConfig) -> tuple[StageOutputs, dict]:
    """The stage outputs with the COR and Hertz models replayed on the identification (:func:`replay_models`),
    and the replay itself (for the figures)."""
    sim = replay_models(assemble_results(stages), track, rig)
    dev = sim["deviations"]
    stage = SimulationStage(simulation=Simulation.of_deviations({"cor_model": dev.get("cor_model"),
                                                                 "hertz_model": dev.get("hertz_model")}),
                            warnings=[f"simulation {name}: {msg}" for name, msg in sim["errors"].items()])
    return replace(stages, simulation=stage), sim


def _with_discrepancy(stages: StageOutputs, track: DicTrack, rig: RigConfig):
    """The stage outputs with the discrepancy analysis and the impacts re-measured under its final model, and
    the analysis' run (None when it was skipped or failed)."""
    from vibro_discrepancy.engine import discrepancy_for_results
    from vibro_discrepancy.reidentify import reidentification

    block, run, error = discrepancy_for_results(assemble_results(stages), track, rig)
    stage = DiscrepancyStage(discrepancy=block, warnings=[error] if error else [],
                             reidentification=reidentification(block.findings, run))
    return replace(stages, discrepancy=stage), run


def _with_ball_spin(stages: StageOutputs, track: DicTrack) -> ResultsDocument:
    """The final document: the ball's spin per flight and impact of the final flights and impacts."""
    final = assemble_results(stages)
    spin = BallSpinStage(section=ball_spin_section(track, final.flights, final.impacts))
    return assemble_results(replace(stages, ball_spin=spin))


def _write_report(document: ResultsDocument, ident, track: DicTrack, sim: dict, disc_run, out: Path) -> None:
    """The figures (PNG, each with an SVG twin) and report.html of an analysed recording."""
    from vibro_app.report import REPORT_HTML, write_figures, write_html  # matplotlib: only for the report

    figs = write_figures(track, ident, out, sim, impacts=document.impacts)
    if disc_run is not None:
        fig = _write_discrepancy_figure(disc_run, out / DISCREPANCY_PNG)
        if fig is not None:
            figs["discrepancy"] = fig
    write_html(document, figs, out / REPORT_HTML)
