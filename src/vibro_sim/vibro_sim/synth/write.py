"""Write a synthetic recording (rig.yaml, frames/, accel.csv; or a lab's files, :mod:`.lab_files`) and its truth
file beside it."""

from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vibro_io.accel import AccelData, write_accel
from vibro_io.camera_calibration import write_camera_info
from vibro_io.outputs import OutputError, atomic_path, atomic_write_text, prepare_output_dir, prepare_output_file
from vibro_io.rig import (
    AccelConfig,
    BallConfig,
    CameraConfig,
    DicConfig,
    ExcitationConfig,
    RigConfig,
    Roi,
    SetupConfig,
    StructureConfig,
    check_rois_in_image,
    write_rig,
)
from vibro_model.heap import steady_heap
from vibro_model.units import m_to_mm, um_to_mm

from .accel import DaqSettings, make_accel
from .lab_files import ACCEL_TDMS, LAB_OUTPUTS, MrawWriter, lab_files_truth, write_accel_tdms
from .lens import CAMERA_INFO_FILE, Lens, lens_truth, synth_calibration
from .render import Renderer, choose_layout, quantise
from .scenario import STRUCTURE_MASS_KG, SynthConfig, SynthError, build_models, effects_truth
from .sensor_noise import read_noise
from .spin import spin_angle, spin_rate
from .trajectory import regime, simulate_window

log = logging.getLogger(__name__)

SUBSET_PX = 31
MESH_STEP_PX = 10
BLUR_SUBSAMPLES = 7
#: frames stored uncompressed (lossless either way; the read noise leaves a frame ~35 % to compress): PNG without
#: deflate or row filters, 77 kB at 160 x 480 (OpenCV's default ~51 kB), written in 0.14 ms and decoded in 0.05 ms
#: (default: 0.51 and 0.46 ms) by every reader after; TIFF without LZW, 154 kB (105 kB), 0.03 and 0.01 ms (1.7
#: and 0.5 ms)
FRAME_PARAMS = {".png": [cv2.IMWRITE_PNG_COMPRESSION, 0, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE],
                ".tif": [cv2.IMWRITE_TIFF_COMPRESSION, 1]}
ACCEL_COLUMNS = AccelConfig(file="accel.csv", time_column="time_s", upper_column="upper_ms2",
                            lower_column="lower_ms2")


def truth_path(out_dir: str | Path) -> Path:
    """``DIR.truth.json`` beside (never inside) the recording directory ``DIR``."""
    out_dir = Path(out_dir)
    return out_dir.parent / (out_dir.name + ".truth.json")


#: what a synthetic recording folder holds (what --overwrite may replace), lab files (--lab-files) included
RECORDING_OUTPUTS = ("rig.yaml", "accel.csv", "frames/*.png", "frames/*.tif", CAMERA_INFO_FILE, *LAB_OUTPUTS)


def _prepare_dir(out_dir: Path, overwrite: bool, lab_files: bool = False) -> None:
    """An empty recording folder (an earlier synthetic recording only replaced with ``overwrite``), and
    no truth file beside it (an earlier one removed with ``overwrite``, so it never outlives its frames).
    ``lab_files``: no frames/ folder (it would win over the camera file)."""
    tp = truth_path(out_dir)
    try:
        prepare_output_file(tp, overwrite=overwrite)
        prepare_output_dir(out_dir, overwrite=overwrite, owned=RECORDING_OUTPUTS, command="synth")
        tp.unlink(missing_ok=True)
        if not lab_files:
            (out_dir / "frames").mkdir()
    except OutputError as exc:
        raise SynthError(f"--out {exc}") from None
    except OSError as exc:
        raise SynthError(f"--out {out_dir}: cannot prepare ({exc.strerror or exc})") from None


def _drift_mm(t: np.ndarray, cfg: SynthConfig, mm_per_px: float) -> np.ndarray:
    """Slow camera drift (apparent upward scene shift, mm): a 0.4 Hz sway plus a ramp, 0 at t=0."""
    if not (cfg.still and cfg.drift):
        return np.zeros_like(t)
    duration = max(t[-1] - t[0], 1e-9)
    return cfg.drift_px * mm_per_px * (0.7 * np.sin(2 * math.pi * 0.4 * t) + 0.3 * (t - t[0]) / duration)


def synthesize(out_dir: str | Path, config: SynthConfig | None = None, *, overwrite: bool = False,
               progress: bool | None = None, lab_files: bool = False) -> dict[str, Any]:
    """Write a complete synthetic recording to ``out_dir`` and ``out_dir.truth.json``.

    Returns the truth mapping (also written to the truth file). ``progress``: show a
    tqdm bar on stderr (None = only when stderr is a terminal). ``lab_files``: the video as an 8-bit
    Photron MRAW (video.mraw + video.cih, streamed frame by frame) and the accelerometers as an NI TDMS
    (accel.tdms) instead of frames/ and accel.csv, and no rig.yaml (a lab makes it with ``vibro init``;
    the truth's ``lab_files`` names the accelerometers block to add). Raises :class:`SynthError` for bad
    configuration or an unusable output path.
    """
    cfg = config or SynthConfig()
    out_dir = Path(out_dir)
    if str(out_dir).strip() in ("", "."):
        raise SynthError("--out: give a new directory for the recording")
    if lab_files and (cfg.tiff16 or cfg.bits12):
        raise SynthError("--lab-files writes an 8-bit MRAW: leave out --tiff16 and --bits12")
    rng = np.random.default_rng(cfg.seed)
    phase = float(rng.uniform(0.0, 2 * math.pi)) if cfg.phase_rad is None else float(cfg.phase_rad)
    models = build_models(cfg, phase)
    traj = simulate_window(cfg, models)
    S = models.structure
    try:
        layout = choose_layout(cfg.width_px, cfg.height_px, cfg.ball_diameter_mm, cfg.gap_mm,
                               amplitude_mm=m_to_mm(S.bound(0)), mm_per_px=cfg.mm_per_px, subset_px=SUBSET_PX,
                               drift_px=cfg.drift_px if cfg.still and cfg.drift else 0.0)
    except ValueError as exc:
        raise SynthError(f"image layout: {exc}") from None
    _prepare_dir(out_dir, overwrite, lab_files)
    steady_heap()   # each frame makes and drops ~1 MB of spectra: no heap trim and regrowth per frame
    render_rng = np.random.default_rng([cfg.seed, 1])
    noise_rng = np.random.default_rng([cfg.seed, 2])
    renderer = Renderer(layout, render_rng, drift=cfg.still and cfg.drift, spin=models.spinning,
                        ball_surface=cfg.ball_surface, light_deg=cfg.light_deg)
    # the lens the frames are seen through (vibro synth --lens-k1): none by default
    lens = Lens(synth_calibration(cfg.width_px, cfg.height_px, cfg.lens_k1, cfg.lens_k2)) \
        if cfg.lens_k1 or cfg.lens_k2 else None
    calibration = CAMERA_INFO_FILE if lens is not None and cfg.lens_calibration_file else None

    t = traj.frame_t_s
    ball_mm = m_to_mm(traj.ball_m)
    struct_mm = m_to_mm(traj.structure_m)
    drift = _drift_mm(t, cfg, layout.mm_per_px)

    rig = RigConfig(
        camera=CameraConfig(fps=cfg.fps, t0_s=0.0, mm_per_px=layout.mm_per_px, calibration=calibration),
        ball=BallConfig(mass_kg=cfg.ball_mass_kg, diameter_mm=cfg.ball_diameter_mm,
                        youngs_modulus_pa=models.cavity.ball_E_pa, poisson_ratio=models.cavity.ball_nu),
        structure=StructureConfig(gap_mm=cfg.gap_mm, mass_kg=STRUCTURE_MASS_KG,
                                  youngs_modulus_pa=models.cavity.plate_E_pa,
                                  poisson_ratio=models.cavity.plate_nu),
        excitation=ExcitationConfig(frequency_hz=cfg.frequency_hz,
                                    acceleration_mps2=None if cfg.still or cfg.accel_mps2 <= 0 else cfg.accel_mps2),
        dic=_dic_config(cfg, renderer, ball_mm[0] + drift[0], struct_mm[0] + drift[0]),
        accelerometers=ACCEL_COLUMNS if cfg.accel else None,
        path=str(out_dir / "rig.yaml"),
        setup=SetupConfig(axis_tilt_deg=float(cfg.axis_tilt_deg)),
    )
    check_rois_in_image(rig, cfg.height_px, cfg.width_px)

    angle = _ball_angle(models, traj)
    images = _frame_images(cfg, renderer, traj, drift, noise_rng, angle, lens=lens)
    if lab_files:
        _write_mraw(out_dir, cfg, images, progress)
    else:
        _write_frames(out_dir / "frames", cfg, images, progress)

    if cfg.accel:
        daq = DaqSettings(rate_hz=cfg.accel_rate_hz, noise_mps2=cfg.accel_noise_mps2,
                          clock_offset_s=cfg.clock_offset_s, clock_rate_ppm=cfg.daq_clock_ppm)
        sig = make_accel(S, traj.result.impacts, cfg.ball_mass_kg, (float(t[0]), float(t[-1])), daq, noise_rng)
        if lab_files:
            with atomic_path(out_dir / ACCEL_TDMS) as tmp:
                write_accel_tdms(tmp, sig.t_daq_s, sig.upper_ms2, sig.lower_ms2, cfg.accel_rate_hz)
        else:
            with atomic_path(out_dir / "accel.csv") as tmp:
                write_accel(tmp, AccelData(sig.t_daq_s, sig.upper_ms2, sig.lower_ms2), ACCEL_COLUMNS)

    truth = _truth(cfg, models, traj, layout, phase, drift, rig)
    if lens is not None:
        truth["lens"] = lens_truth(lens.calib, calibration, rig.dic.structure_roi)
        if calibration is not None:
            with atomic_path(out_dir / calibration) as tmp:
                write_camera_info(tmp, lens.calib, comment="vibro synth: the synthetic camera's lens (exact)")
    if models.spinning:
        truth["spin"] = _spin_truth(cfg, models, traj, truth)
    if lab_files:
        truth["lab_files"] = lab_files_truth(cfg.accel)
    else:
        # rig.yaml last: a synth interrupted while writing frames leaves no rig.yaml, so the half-written
        # folder is refused as a recording instead of being read as a shorter one (lab files: the MRAW's
        # header is written last, :class:`MrawWriter`)
        with atomic_path(out_dir / "rig.yaml") as tmp:
            write_rig(rig, tmp)
    atomic_write_text(truth_path(out_dir), json.dumps(truth, indent=1))
    return truth


def _dic_config(cfg: SynthConfig, renderer: Renderer, ball_mm0: float, structure_mm0: float) -> DicConfig:
    """rig.yaml's dic block: a speckled or shiny ball by its DIC mesh (a ROI inside the disc), a plain ball by its
    outline (a box around the whole ball)."""
    outline = cfg.ball_surface == "plain"
    ball_roi = renderer.outline_roi(ball_mm0) if outline else renderer.ball_roi(ball_mm0, SUBSET_PX)
    return DicConfig(subset_px=SUBSET_PX, mesh_step_px=MESH_STEP_PX, ball_roi=Roi(*ball_roi),
                     structure_roi=Roi(*renderer.structure_roi(structure_mm0)),
                     ball_method="outline" if outline else "mesh")


def _ball_angle(models, traj):
    """The ball texture's angle (rad, + counter-clockwise on screen, 0 at frame 0) as a function of camera
    time (s), or None when the ball does not spin."""
    if not models.spinning:
        return None
    imps = traj.result.impacts
    times = np.array([i.t_s for i in imps], dtype=float)
    index = np.array([i.index for i in imps], dtype=int)
    return lambda t: spin_angle(t, times, index, models.spins_rad_s)


def _spin_truth(cfg: SynthConfig, models, traj, truth: dict[str, Any]) -> dict[str, Any]:
    """The truth's ``spin`` section: the angle at each frame, each flight's spin and each impact's change."""
    imps = traj.result.impacts
    times = np.array([i.t_s for i in imps], dtype=float)
    index = np.array([i.index for i in imps], dtype=int)
    spins = models.spins_rad_s
    angle = spin_angle(traj.frame_t_s, times, index, spins)
    flights = [{**{k: f[k] for k in ("index", "t_start", "t_end", "direction")},
                "omega_rad_s": float(spin_rate(0.5 * (f["t_start"] + f["t_end"]), times, index, spins))}
               for f in truth["flights"]]
    impacts = [{"index": j["index"], "t": j["t"], "plate": j["plate"],
                "omega_before_rad_s": float(spins[j["sim_index"]]),
                "omega_after_rad_s": float(spins[j["sim_index"] + 1]),
                "spin_change_rad_s": float(spins[j["sim_index"] + 1] - spins[j["sim_index"]])}
               for j in truth["impacts"]]
    return {"convention": "in-plane rotation of the ball's texture about its centre, rad, + counter-clockwise as "
                          "the camera sees the image, 0 at frame 0; each flight spins at a constant rate",
            "spin_rad_s": cfg.spin_rad_s, "spin_sigma_rad_s": cfg.spin_sigma_rad_s,
            "spin_cor_coupling_s_per_rad": cfg.spin_cor_coupling_s_per_rad,
            "cor_note": "impacts[].cor includes spin_cor_coupling_s_per_rad x spin_change_rad_s; cor_law does not",
            "frames_rot_rad": angle.tolist(), "flights": flights, "impacts": impacts}


def _progress(images, n: int, progress: bool | None):
    """``images`` behind a tqdm bar on stderr (``progress`` None: only when stderr is a terminal)."""
    from tqdm import tqdm

    show = sys.stderr.isatty() if progress is None else progress
    return tqdm(images, total=n, desc="synth frames", unit="frame", disable=not show, file=sys.stderr)


def _write_frames(folder: Path, cfg: SynthConfig, images, progress: bool | None) -> None:
    """One PNG (TIFF for 16-bit) per frame of ``images`` (:func:`_frame_images`) into ``folder``."""
    ext = ".tif" if cfg.tiff16 or cfg.bits12 else ".png"
    params = FRAME_PARAMS[ext]
    for k, image in enumerate(_progress(images, cfg.frames, progress)):
        if not cv2.imwrite(str(folder / f"{k:06d}{ext}"), image, params):
            raise SynthError(f"{folder / f'{k:06d}{ext}'}: cannot write frame")


def _write_mraw(folder: Path, cfg: SynthConfig, images, progress: bool | None) -> None:
    """``images`` (:func:`_frame_images`, 8-bit) streamed into folder/video.mraw, its .cih header last."""
    try:
        with MrawWriter(folder, cfg.frames, cfg.fps, cfg.exposure_s) as mraw:
            for image in _progress(images, cfg.frames, progress):
                mraw.write(image)
    except OSError as exc:
        raise SynthError(f"{folder}: cannot write the MRAW ({exc.strerror or exc})") from None


def _frame_images(cfg: SynthConfig, renderer: Renderer, traj, drift: np.ndarray, rng: np.random.Generator,
                  angle=None, lens: Lens | None = None):
    """The recording's frames, rendered one at a time as they are asked for (quantised as written); seen through
    ``lens`` (:mod:`.lens`) when given, before the sensor's flicker and noise."""
    t = traj.frame_t_s
    S = traj.result.structure
    flick_phase = float(rng.uniform(0, 2 * math.pi))
    if cfg.blur:
        offsets = cfg.exposure_s * (np.arange(BLUR_SUBSAMPLES) + 0.5 - BLUR_SUBSAMPLES / 2) / BLUR_SUBSAMPLES
    for k in range(t.size):
        if cfg.blur and not cfg.still:
            ts = t[k] + offsets
            ball = m_to_mm(np.asarray(traj.result.sample(ts)))
            struct = m_to_mm(np.asarray(S.position(ts)))
            img = renderer.render_blurred(struct, ball, drift[k], None if angle is None else angle(ts))
        else:
            img = renderer.render(m_to_mm(traj.structure_m[k]), m_to_mm(traj.ball_m[k]), drift[k],
                                  0.0 if angle is None else float(angle(t[k])))
        if lens is not None:
            img = lens.apply(img)
        gain = 1.0 + cfg.flicker * (0.7 * math.sin(2 * math.pi * 100.0 * t[k] + flick_phase)
                                    + 0.3 * float(rng.standard_normal()))
        img = img * gain
        if cfg.noise_gray > 0:
            img += read_noise(rng, img.shape, cfg.noise_gray)
        yield quantise(img, cfg.tiff16, cfg.jpeg_quality, cfg.bits12)


def _truth(cfg, models, traj, layout, phase, drift, rig) -> dict[str, Any]:
    S = models.structure
    first = traj.impacts[0].index if traj.impacts else 0
    plain = models.window_laws(first)[1]
    impacts = [{"index": j, "t": i.t_s, "plate": i.plate, "cor": i.cor,
                "v_ball_before": i.v_ball_before_mps, "v_ball_after": i.v_ball_after_mps,
                "v_structure": i.v_structure_mps, "sim_index": i.index,
                # the COR law's value before the per-impact scatter
                "cor_law": float(plain.cor(i.plate, i.v_rel_before_mps, i.index)) if plain is not None else i.cor}
               for j, i in enumerate(traj.impacts)]
    first_flight = traj.flights[0].index if traj.flights else 0
    flights = [{"index": f.index - first_flight, "t_start": f.t_start_s, "t_end": f.t_end_s,
                "direction": f.direction, "friction_n": f.mean_force_n,
                "start_plate": f.start_plate, "end_plate": f.end_plate}
               for f in traj.flights]
    cfg_dict = cfg.to_dict()
    cfg_dict["phase_rad"] = phase
    truth: dict[str, Any] = {
        "schema": "vibro.truth/1",
        "effects": effects_truth(cfg),
        "structure": {"amplitude_mm": m_to_mm(S.amplitude_m), "frequency_hz": S.frequency_hz,
                      "phase_rad": phase, "offset_mm": m_to_mm(S.offset_m),
                      "h2_ratio": S.h2_ratio, "h3_ratio": S.h3_ratio,
                      "h2_phase_rad": S.h2_phase_rad, "h3_phase_rad": S.h3_phase_rad,
                      "accel_ms2": S.amplitude_m * S.omega_rad_s ** 2,
                      "convention": "Y_s = B + A[sin(th) + h2 sin(2 th + p2) + h3 sin(3 th + p3)], th = w t + phase"},
        "frames": {"t_s": traj.frame_t_s.tolist(), "ball_mm": m_to_mm(traj.ball_m).tolist(),
                   "structure_mm": m_to_mm(traj.structure_m).tolist()},
        "impacts": impacts,
        "flights": flights,
        "free_play_mm": m_to_mm(models.cavity.free_play_m),
        "ball_offset_mm": float(m_to_mm(traj.ball_m[0] - traj.structure_m[0])),
        "gravity_ms2": models.cavity.gravity_mps2,
        "g_eff_ms2": models.cavity.g_eff_mps2,
        "ball_mass_kg": models.cavity.mass_kg,
        "clock_offset_s": cfg.clock_offset_s,
        "daq_clock_ppm": cfg.daq_clock_ppm,
        "clock_convention": "accel.csv time_s = camera time + clock_offset_s + daq_clock_ppm * 1e-6 * camera time",
        "image": {"mm_per_px": layout.mm_per_px, "width_px": layout.width_px, "height_px": layout.height_px,
                  "ball_radius_px": layout.ball_radius_px, "row_mid": layout.row_mid,
                  "ball_roi": rig.dic.ball_roi.as_list(), "structure_roi": rig.dic.structure_roi.as_list()},
        "models": {"restitution": repr(models.restitution), "force": repr(models.force)},
        "axis_tilt_deg": float(cfg.axis_tilt_deg),   # declared in rig.yaml setup.axis_tilt_deg
        "baseline": {"cor": cfg.cor, "force": "none",
                     "gravity": ("vertical" if cfg.axis_tilt_deg == 0 else
                                 f"along the axis declared {cfg.axis_tilt_deg:g} deg from vertical: g cos(tilt)"),
                     "structure": "pure sine", "note": "what the effects modify"},
        "regime": regime(traj, cfg.frequency_hz) if not cfg.still else None,
        # the ball riding a plate (COR model: a rebound slower than its stick speed): from the landing to the
        # release, when the plate's downward acceleration exceeds g (clipped to the filmed interval)
        "contacts": [{"start_s": max(s.t_start_s, float(traj.frame_t_s[0])),
                      "end_s": min(s.t_end_s, float(traj.frame_t_s[-1])), "plate": s.plate,
                      "starts_before_recording": bool(s.t_start_s < traj.frame_t_s[0]),
                      "ends_after_recording": bool(s.t_end_s > traj.frame_t_s[-1])}
                     for s in traj.result.stuck
                     if s.t_end_s > traj.frame_t_s[0] and s.t_start_s < traj.frame_t_s[-1]] if not cfg.still else [],
        "config": cfg_dict,
    }
    if hasattr(S, "tone_frequency_hz"):
        truth["structure"].update(tone_amplitude_mm=m_to_mm(S.tone_amplitude_m), tone_frequency_hz=S.tone_frequency_hz,
                                  tone_phase_rad=S.tone_phase_rad,
                                  convention=truth["structure"]["convention"] + " + tone_amplitude sin(2 pi "
                                  "tone_frequency t + tone_phase)")
    if models.plate_step is not None:
        truth["plate_step"] = {"plate": "top", "t_s": models.plate_step["step_time_s"],
                               "step_mm": um_to_mm(models.plate_step["step_um"]),
                               "note": "the upper plate is step_mm higher (the cavity larger) from t_s on"}
    if models.plate_creep is not None:
        truth["plate_creep"] = {"plate": "top", "rate_mm_per_s": um_to_mm(models.plate_creep["creep_um_per_s"]),
                                "note": ("the upper plate is rate_mm_per_s * t higher than where it moves with the "
                                         "structure (t camera time, s): its velocity is the structure's plus "
                                         "rate_mm_per_s, which the impacts on it meet")}
    if cfg.still and cfg.drift:
        truth["camera_drift_mm"] = drift.tolist()
        truth["camera_drift_note"] = ("apparent upward shift of the whole scene; DIC measures "
                                      "frames.*_mm - frames.*_mm[0] + camera_drift_mm")
    return truth
