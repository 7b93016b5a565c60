"""``analyze_recording``: DIC -> identification -> simulation (COR and Hertz models) -> results + report.

The same cores as the nodes: vibro_dic.tracker.track_recording, vibro_fit.identify (which runs the
streaming fitter), vibro_sim.replay.simulate_measured (COR and Hertz models), vibro_sim.deviation (Eq. 18).

Replay of the identified motion (``replay_models``): the structure is the fitted sine (track
coordinates, m); the ball starts at the start of the first free flight with that flight's position and
velocity, moved into the cavity frame by the measured offset c0 between ball and cavity centre at frame 0
(from the impacts' relative positions); each impact uses its identified COR (PerImpact, the mean after
the last) and each flight its identified friction force (0 for a flight that is not free). D is computed
on the measured ball displacement as DIC gives it (mm since frame 0).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np

from vibro_io.accel import load_accel
from vibro_io.dictrack import DicTrack, read_dic_csv, write_dic_csv
from vibro_io.errors import RecordingError
from vibro_io.recording import open_recording
from vibro_io.rig import RigConfig, load_rig

log = logging.getLogger(__name__)


def _bar(total: int, progress: bool, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="step", disable=not progress or not sys.stderr.isatty(),
                leave=False, file=sys.stderr)


def cavity_offset_mm(ident, rig: RigConfig) -> float:
    """c0 = ball centre minus cavity centre at frame 0 (mm), from the plate levels of the impacts."""
    return float(ident.plate_levels.get("offset_mm", 0.0))


def replay_models(ident, track: DicTrack, rig: RigConfig) -> dict:
    """Simulate the COR and Hertz models with the identified parameters (vibro_sim.replay); D (Eq. 18)
    of each against the measured ball displacement (track coordinates, mm since frame 0).

    Returns {"t_s", "measured_mm", "curves": {name: mm}, "deviations": {name: D}, "errors": {name: msg}}.
    """
    from vibro_sim.deviation import deviation
    from vibro_sim.params import BallCavity
    from vibro_sim.replay import ReplayInputs, simulate_measured
    from vibro_sim.structure import StructureMotion

    out = {"t_s": None, "measured_mm": None, "curves": {}, "deviations": {}, "errors": {}}
    free = [f for f in ident.flights if f.is_free]
    if not free or not ident.impacts:
        out["errors"]["all"] = "no free flight or no impact: nothing to replay"
        return out
    fl0 = free[0]
    s = ident.structure
    # the fitted sine, in track coordinates (m); c0 moves the ball track into the cavity frame
    structure = StructureMotion(s.amplitude_mm * 1e-3, s.frequency_hz, s.phase_rad, s.offset_mm * 1e-3)
    cavity = BallCavity(mass_kg=rig.ball.mass_kg, radius_m=0.5e-3 * rig.ball.diameter_mm,
                        free_play_m=1e-3 * rig.free_play_mm, ball_E_pa=rig.ball.youngs_modulus_pa,
                        ball_nu=rig.ball.poisson_ratio, plate_E_pa=rig.structure.youngs_modulus_pa,
                        plate_nu=rig.structure.poisson_ratio)
    c0 = cavity_offset_mm(ident, rig)
    b = rig.free_play_mm
    t0 = fl0.t_start_s
    y_rel0 = float(fl0.position_mm(t0)) + c0 - float(s.position_mm(t0))
    y_rel0 = float(np.clip(y_rel0, -0.999 * b, 0.999 * b))
    v_rel0 = float(fl0.velocity_ms(t0)) - float(s.velocity_ms(t0))
    by_index = {f.index: f for f in ident.flights}

    def force(k):
        f = by_index.get(k)
        return f.friction_n(ident.mass_kg)[0] if f is not None and f.is_free else 0.0

    imps = ident.impacts
    # flight i ends with impact i; one more flight after the last impact
    forces = [force(i.flight_before) for i in imps] + [force(imps[-1].flight_after)]
    good = track.good & (track.t_s >= t0)
    t = track.t_s[good]
    meas = track.ball_mm[good]
    out["t_s"], out["measured_mm"] = t, meas
    try:
        inputs = ReplayInputs(structure, [i.t_s for i in imps], [i.plate for i in imps], [i.cor for i in imps],
                              forces, t_start_s=float(t0), y_rel_m=1e-3 * y_rel0, v_rel_ms=v_rel0,
                              t_end_s=float(t[-1]))
    except ValueError as exc:
        out["errors"]["all"] = str(exc)
        return out
    for name in ("cor_model", "hertz_model"):
        try:
            y_m, _ = simulate_measured(inputs, cavity, t, models=(name,))[name]
            y = 1e3 * y_m - c0
            out["curves"][name] = y
            out["deviations"][name] = float(deviation(t, y, meas))
        except Exception as exc:  # a model failure must not lose the identification
            log.warning("%s replay failed: %s", name, exc)
            out["errors"][name] = str(exc)
    return out


def load_inputs(recording_dir: str | Path, track_csv: str | Path | None, *, progress: bool, dic_method: str,
                out_dir: Path):
    """(rig, track, accel) from a recording: DIC unless ``track_csv`` is given (then frames are not read)."""
    rec_dir = Path(recording_dir)
    if track_csv is not None:
        if not rec_dir.is_dir():
            raise RecordingError(f"{rec_dir}: not a recording directory")
        rig = load_rig(rec_dir / "rig.yaml")
        track = read_dic_csv(track_csv)
        accel = None
        if rig.accelerometers is not None:
            accel = load_accel(rec_dir / rig.accelerometers.file, rig.accelerometers)
        return rig, track, accel
    from vibro_dic.tracker import track_recording

    rec = open_recording(rec_dir)
    rows = list(track_recording(rec, method=dic_method, progress=progress))
    write_dic_csv(out_dir / "dic.csv", rows)
    return rec.rig, DicTrack.from_frames(rows), rec.load_accel()


def analyze_recording(recording_dir: str | Path, out_dir: str | Path, *, progress: bool = True,
                      method: str = "paper", track_csv: str | Path | None = None, dic_method: str = "icgn",
                      report: bool = True, weights: str | None = None) -> dict:
    """Run the whole analysis; writes results.json, flights.csv, impacts.csv, PNG figures and report.html
    into ``out_dir`` (created). Returns the results mapping."""
    from vibro_fit.identify import identify
    from vibro_fit.report import write_figures, write_html
    from vibro_fit.results import results_document, write_csv_tables, write_json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bar = _bar(4, progress, "analyze")
    try:
        bar.set_description("DIC" if track_csv is None else "read track")
        rig, track, accel = load_inputs(recording_dir, track_csv, progress=progress, dic_method=dic_method,
                                        out_dir=out)
        bar.update(1)
        bar.set_description("identify")
        ident = identify(track, rig, accel=accel, method=method, weights=weights)
        bar.update(1)
        bar.set_description("simulate")
        sim = replay_models(ident, track, rig)
        bar.update(1)
        dev = sim["deviations"]
        simulation = {"cor_model": {"deviation": dev.get("cor_model")},
                      "hertz_model": {"deviation": dev.get("hertz_model")}}
        for name, msg in sim["errors"].items():
            ident.warnings.append(f"simulation {name}: {msg}")
        d0 = dev.get("cor_model")
        discrepancy = {"baseline_deviation": d0, "findings": [], "final_deviation": d0}
        doc = results_document(ident, str(recording_dir), simulation, discrepancy)
        write_json(out / "results.json", doc)
        write_csv_tables(ident, out)
        if report:
            bar.set_description("report")
            figs = write_figures(track, ident, out, sim)
            write_html(doc, figs, out / "report.html")
        bar.update(1)
    finally:
        bar.close()
    return doc
