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
from pathlib import Path

from vibro_app.cmd_track import DIC_CSV
from vibro_app.report_files import FIGURE_FILES, REPORT_HTML
from vibro_dic.chunked import track_rows
from vibro_dic.quality import TrackQuality, dic_quality_section
from vibro_fit.cross_checks import consistency_checks, consistency_section
from vibro_fit.plausibility import withhold_results
from vibro_fit.spin import ball_spin_section
from vibro_io.dictrack import DicTrack, read_dic_csv, write_dic_csv
from vibro_io.frames import find_frames_source
from vibro_io.outputs import atomic_path, prepare_output_dir
from vibro_io.recording import load_recording_accel, open_recording
from vibro_io.results_file import write_results
from vibro_io.rig import RigConfig, load_rig
from vibro_model.errors import RecordingError
from vibro_model.results import Simulation
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

    Returns {"t_s", "measured_mm", "curves": {name: mm}, "deviations": {name: D}, "errors": {name: msg}}.
    """
    from vibro_sim.measured import replay_and_score, replay_inputs

    out = {"t_s": None, "measured_mm": None, "curves": {}, "deviations": {}, "errors": {}}
    good = track.good
    offset_m = document.structure.ball_offset_m or 0.0
    try:
        inputs = replay_inputs(document.structure, document.flights, document.impacts, mm_to_m(rig.free_play_mm),
                               float(track.t_s[good][-1]), offset_m)
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
    from vibro_fit.results import CSV_TABLES, RESULTS_JSON

    return (RESULTS_JSON, DIC_CSV, *CSV_TABLES, *FIGURE_FILES.values(), DISCREPANCY_PNG, REPORT_HTML)


def load_inputs(recording_dir: str | Path, track_csv: str | Path | None, *, progress: bool, dic_method: str,
                out_dir: Path, overwrite: bool = False, quality=None, workers: int | None = None,
                scheduler: str | None = None):
    """(rig, track, accel) from a recording: DIC unless ``track_csv`` is given (then frames are not read).

    DIC runs in this process, or in chunks on Dask workers (``workers`` > 1 local processes, or the cluster
    at ``scheduler``): the same track and quality (:func:`vibro_dic.chunked.track_rows`). The inputs are
    opened (and validated) before ``out_dir`` is prepared (:func:`prepare_output_dir`); with DIC the track is
    written to ``out_dir/dic.csv`` and ``quality`` (a :class:`vibro_dic.quality.TrackQuality`, optional)
    receives the texture check and the correlation quality."""
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
    rows = list(track_rows(rec, workers=workers, scheduler=scheduler, method=dic_method, progress=progress,
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

    try:
        with atomic_path(path) as tmp:
            if write_discrepancy_figure(disc_run, tmp) is None:
                raise _NoFigure
    except _NoFigure:
        return None
    return path


def analyze_recording(recording_dir: str | Path, out_dir: str | Path, *, progress: bool = True,
                      method: str = "paper", track_csv: str | Path | None = None, dic_method: str = "icgn",
                      report: bool = True, weights: str | None = None, overwrite: bool = False,
                      workers: int | None = None, scheduler: str | None = None) -> dict:
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
    method : str
        Impact identification: ``"paper"`` (Eq. 15-16) or ``"joint"`` (:func:`vibro_fit.identify.identify`).
    track_csv : str or Path, optional
        A DIC track (dic.csv) to use instead of tracking the frames.
    dic_method : str
        The DIC sub-pixel method: ``"icgn"`` or ``"parabolic"`` (:mod:`vibro_dic.tracker`).
    report : bool
        Write the figures and report.html.
    weights : str, optional
        Flight-fit weights (``"dic_valid"``: by the valid ball subsets per frame).
    overwrite : bool
        Replace an earlier analysis's files in ``out_dir``.
    workers : int, optional
        DIC in chunks on a new local Dask cluster of this many processes.
    scheduler : str, optional
        DIC in chunks on the Dask scheduler at this address.

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
    from vibro_discrepancy.engine import discrepancy_for_results
    from vibro_discrepancy.reidentify import reidentify_document
    from vibro_fit.identify import identify
    from vibro_fit.results import RESULTS_JSON, cor_statistics_section, results_model, write_csv_tables

    out = Path(out_dir)
    bar = _bar(4, progress, "analyze")
    try:
        bar.set_description("DIC" if track_csv is None else "read track")
        quality = TrackQuality() if track_csv is None else None
        rig, track, accel = load_inputs(recording_dir, track_csv, progress=progress, dic_method=dic_method,
                                        out_dir=out, overwrite=overwrite, quality=quality, workers=workers,
                                        scheduler=scheduler)
        dic_warnings = [] if quality is None else quality.check()  # refuses a body lost in most frames
        bar.update(1)
        bar.set_description("identify")
        ident = identify(track, rig, accel=accel, method=method, weights=weights)
        findings, evidence = consistency_checks(ident, track, rig, accel, _frames_source_name(recording_dir,
                                                                                             track_csv))
        bar.update(1)
        bar.set_description("simulate")
        document = results_model(ident, str(recording_dir))
        if quality is not None:
            document.sections["dic_quality"] = dic_quality_section(quality.texture, quality)
            document.warnings += [f"DIC: {w}" for w in quality.texture.warnings() + dic_warnings]
        document.sections["consistency"] = consistency_section(findings, evidence)
        document.warnings += [f"consistency: {f.message}" for f in findings]
        refusal = next((f for f in findings if f.refuses), None)
        if refusal is not None:
            withhold_results(document, findings)
            write_results(out / RESULTS_JSON, document)
            write_csv_tables(document, out)
            raise RecordingError(f"{refusal.message} (results withheld: {out / RESULTS_JSON} has no COR table, "
                                 "see its 'consistency' section)")
        sim = replay_models(document, track, rig)
        bar.update(1)
        dev = sim["deviations"]
        document.warnings += [f"simulation {name}: {msg}" for name, msg in sim["errors"].items()]
        document.simulation = Simulation.of_deviations({"cor_model": dev.get("cor_model"),
                                                        "hertz_model": dev.get("hertz_model")})
        bar.set_description("discrepancy")
        document.discrepancy, disc_run, disc_error = discrepancy_for_results(document, track, rig)
        if disc_error:
            document.warnings.append(disc_error)
        # the physics found corrects the measurement: impacts re-measured under the final model
        document = reidentify_document(document, disc_run)
        document.sections["cor_statistics"] = cor_statistics_section(document.impacts)
        document.sections["ball_spin"] = ball_spin_section(track, document.flights, document.impacts)
        write_results(out / RESULTS_JSON, document)
        write_csv_tables(document, out)
        doc = document.to_dict()
        if report:
            from vibro_app.report import REPORT_HTML, write_figures, write_html  # matplotlib: only for the report

            bar.set_description("report")
            figs = write_figures(track, ident, out, sim, impacts=document.impacts)
            if disc_run is not None:
                fig = _write_discrepancy_figure(disc_run, out / DISCREPANCY_PNG)
                if fig is not None:
                    figs["discrepancy"] = fig
            write_html(document, figs, out / REPORT_HTML)
        bar.update(1)
    finally:
        bar.close()
    return doc
