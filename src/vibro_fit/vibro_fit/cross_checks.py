"""The instruments check each other: camera time base against the drive, accelerometers against DIC.

The camera and the two accelerometers measure the same structure motion: the camera its displacement
(the fitted sine Y_s = A sin(2 pi f t + phi) + B, Eq. 2/13), each accelerometer (both plates ride on the
structure) its acceleration, whose drive tone is Y_s'' = -A (2 pi f)^2 sin(2 pi f t + phi).

- **Time base** (:func:`time_base_step`): the structure's phase advances evenly with the frame index. A
  lost frame in a video makes every later frame show the motion one frame period later than its index
  says (a duplicated frame, one period earlier): the sine fit's residual then carries a step
  tau * Y_s'(t) from that frame on. The step is scanned at every frame in O(N) (the residual projected on
  tau * Y_s' * H(k >= j), with the sine's own parameters projected out); a step within a quarter of a
  frame of +-1 frame period and far above the noise (:data:`STEP_Z` sigmas beyond the look-elsewhere
  level) locates the frame. A wrong ``camera.fps`` is a steady drift instead (the structure's frequency
  on the camera clock differs from the drive's on the DAQ clock), named by :mod:`vibro_fit.rig_consistency`
  and repeated here as a time-base finding.
- **Accelerometer drive tone** (:func:`accel_drive_tone`): each channel's component at the structure's
  frequency (low-passed, least squares on the camera clock through the clock offset) against the DIC
  acceleration: the ratio's magnitude checks the unit and sensitivity (9.81 = the data are in g, read as
  m/s^2), its phase the polarity (180 deg: the channel is inverted).
- **Plates** (:func:`plate_attribution`): each impact's plate from DIC (which plate the ball hit) against
  the accelerometer channel that responds strongest: every one opposite means the channels are swapped.
- **Tracking** (:func:`tracking_check`): a body lost in more than half the frames is refused, with the words
  ``vibro analyze`` refuses its own tracking with (:mod:`vibro_io.track_loss`), so a graph run and a track read
  from dic.csv refuse it too.

Each check returns :class:`~vibro_fit.plausibility.Finding` objects (what, the numbers, the rig.yaml key).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from vibro_io.track_loss import BODY_KEYS, lost_refusal, track_losses

from .accel_impacts import ClockLine
from .plausibility import Finding

G0 = 9.80665  # m/s^2 per g (standard gravity, the unit g of accelerometers)
#: a step must exceed the look-elsewhere level sqrt(2 ln N) by this many sigmas
STEP_Z = 6.0
#: a step within this fraction of a frame of +-1 frame period is a lost/duplicated frame
STEP_FRAME_TOL = 0.25
#: the step must explain at least this fraction of the sine fit's residual sum of squares
STEP_SSE_FRACTION = 0.25
#: frames kept on each side of a candidate step (a step closer to an end is not located)
STEP_MIN_SIDE = 10
#: relative tolerance of the accelerometer/DIC drive-tone amplitude ratio (sensor calibration, image scale)
AMPLITUDE_TOL = 0.10
#: a channel whose drive tone is more than this far (rad) from the DIC acceleration's phase is inverted
POLARITY_LIMIT_RAD = math.pi / 2.0
#: fraction of matched impacts whose accelerometer plate is opposite to DIC's for "swapped"
SWAP_FRACTION = 0.8
SWAP_MIN_IMPACTS = 3


def _design(structure, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(model y mm, Jacobian N x 5 over (A, f, psi, B, fdot), velocity mm/s) of the sine fit at ``t_s``. fdot
    (Hz/s) is a drive whose frequency drifts linearly, phase pi fdot (t - t_ref)^2 more (0 in the fit): its
    smooth phase curve is not a time-base step, and left out of the null model the best single step took up
    part of it (a drift of 0.02 Hz/s over a 3 s take was refused as a frame lost at 2.4 s, 0.79 frame)."""
    a, f, psi, b = structure.params_ref
    dt = t_s - structure.t_ref_s
    w = 2.0 * math.pi * f
    th = w * dt + psi
    s, c = np.sin(th), np.cos(th)
    jac = np.column_stack([s, a * 2.0 * math.pi * dt * c, a * c, np.ones_like(dt), a * math.pi * dt * dt * c])
    return a * s + b, jac, a * w * c


def step_scan(t_s: np.ndarray, y_mm: np.ndarray, structure) -> dict | None:
    """Best single time-base step of a structure track against its sine fit ``structure``.

    Model: y_k = sine(t_k) + tau Y_s'(t_k) H(k >= j) + noise, the sine's parameters and a linear frequency drift
    free (projected out).
    Returns {"index": j (position in the arrays), "tau_s", "tau_std_s", "z", "sse_fraction" (of the
    residual sum of squares the step explains), "look_elsewhere_z", "n"} or None when the track is too short.
    """
    t = np.asarray(t_s, float)
    y = np.asarray(y_mm, float)
    n = t.size
    if n < 2 * STEP_MIN_SIDE + 5:
        return None
    model, jac, v = _design(structure, t)
    r = y - model
    m = jac.T @ jac
    try:
        minv = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        return None
    jr = jac.T @ r
    # sums over k >= j for every j (reverse cumulative sums)
    s_gr = np.cumsum((v * r)[::-1])[::-1]
    s_gg = np.cumsum((v * v)[::-1])[::-1]
    s_jg = np.cumsum((jac * v[:, None])[::-1], axis=0)[::-1]
    gr = s_gr - s_jg @ (minv @ jr)
    gg = s_gg - np.einsum("ij,jk,ik->i", s_jg, minv, s_jg)
    valid = np.zeros(n, bool)
    valid[STEP_MIN_SIDE:n - STEP_MIN_SIDE] = True
    valid &= gg > 1e-12 * max(float(s_gg[0]), 1e-300)
    if not valid.any():
        return None
    gain = np.where(valid, gr * gr / np.where(gg > 0, gg, 1.0), -np.inf)
    j = int(np.argmax(gain))
    sse = float(r @ r - jr @ minv @ jr)
    sse_after = max(sse - float(gain[j]), 0.0)
    sigma = math.sqrt(sse_after / max(n - jac.shape[1] - 1, 1))
    tau = float(gr[j] / gg[j])
    tau_std = sigma / math.sqrt(float(gg[j])) if sigma > 0 else 0.0
    return {"index": j, "tau_s": tau, "tau_std_s": tau_std, "z": abs(tau) / tau_std if tau_std > 0 else math.inf,
            "sse_fraction": float(gain[j]) / sse if sse > 0 else 0.0, "look_elsewhere_z": math.sqrt(2 * math.log(n)),
            "n": n, "sigma_mm": sigma}


def time_base_step(track, structure, fps: float, source: str = "the video") -> Finding | None:
    """A lost or duplicated frame located by a step of one frame period in the structure's phase
    (module rules); None when the phase advances evenly. ``track``: a DicTrack (frame, t_s, structure_mm,
    good); ``structure``: its sine fit; ``fps``: the camera rate (frames/s)."""
    good = np.asarray(track.good, bool)
    scan = step_scan(np.asarray(track.t_s)[good], np.asarray(track.structure_mm)[good], structure)
    if scan is None:
        return None
    dt = 1.0 / fps
    frames = float(scan["tau_s"] / dt)
    if scan["z"] < scan["look_elsewhere_z"] + STEP_Z or scan["sse_fraction"] < STEP_SSE_FRACTION:
        return None
    if abs(abs(frames) - 1.0) > STEP_FRAME_TOL:
        return None
    frame = int(np.asarray(track.frame)[good][scan["index"]])
    lost = frames > 0
    phase = 2.0 * math.pi * float(structure.frequency_hz) * scan["tau_s"]
    what = (f"a frame is missing from {source} just before frame {frame} (frames from {frame} on show the motion "
            f"{frames:+.2f} frame periods later than their index says)" if lost else
            f"frame {frame} repeats an earlier one in {source} (frames from {frame} on show the motion "
            f"{frames:+.2f} frame periods earlier than their index says)")
    msg = (f"camera time base: the structure's phase steps by {phase:+.4f} rad ({scan['tau_s'] * 1e3:+.3f} ms "
           f"+- {scan['tau_std_s'] * 1e3:.3f} ms, {frames:+.2f} frame) at frame {frame} of the "
           f"{float(structure.frequency_hz):.3f} Hz sine fit ({scan['z']:.0f} sigma): {what}; every time after "
           f"it is {abs(scan['tau_s']) * 1e3:.3f} ms off: re-export the video without the gap, or give the "
           "frames as numbered image files (a missing number is read as a dropped frame)")
    return Finding("time_base_step", msg, [],
                   {"frame": frame, "step_s": scan["tau_s"], "step_std_s": scan["tau_std_s"],
                    "step_frames": frames, "phase_step_rad": phase, "z": scan["z"],
                    "sse_fraction": scan["sse_fraction"], "residual_sigma_mm": scan["sigma_mm"],
                    "kind": "lost_frame" if lost else "duplicated_frame"}, "refuse", frame)


def time_base_drift(rig_statements, duration_s: float) -> Finding | None:
    """A wrong ``camera.fps`` as a steady phase drift against the drive on the DAQ clock (from the rig.yaml
    statement that names it alone, :mod:`vibro_fit.rig_consistency`); None otherwise."""
    for r in rig_statements or ():
        if list(r.keys) == ["camera.fps"] and "daq_excitation_frequency_hz" in r.measured:
            f_cam = float(r.measured["structure_frequency_hz"])
            f_daq = float(r.measured["daq_excitation_frequency_hz"])
            drift = 2.0 * math.pi * (f_cam - f_daq)
            return Finding("time_base_drift",
                           f"camera time base: the structure's phase drifts by {drift:+.3f} rad/s against the "
                           f"drive on the accelerometers' clock ({drift * duration_s:+.2f} rad over the "
                           f"{duration_s:.3f} s filmed): {r.message}", ["camera.fps"],
                           {"drift_rad_per_s": drift, "structure_frequency_hz": f_cam,
                            "daq_excitation_frequency_hz": f_daq, **dict(r.suggested)}, "warn")
    return None


def drive_tone(t_s: np.ndarray, x: np.ndarray, frequency_hz: float) -> tuple[complex, float, int]:
    """Complex amplitude X of x(t) ~ Re(X exp(i 2 pi f t)) + c by least squares, low-passed at 4 f first
    (impact ringing is in kHz), its standard deviation (|X| units) from the residual and the number of
    independent samples of the low-passed signal."""
    from scipy.signal import butter, sosfiltfilt

    t = np.asarray(t_s, float)
    x = np.asarray(x, float)
    fs = float(1.0 / np.median(np.diff(t)))
    cut = min(4.0 * frequency_hz, 0.4 * fs)
    xl = sosfiltfilt(butter(4, cut, btype="lowpass", fs=fs, output="sos"), x - x.mean())
    w = 2.0 * math.pi * frequency_hz
    t0 = t - t[0]
    design = np.column_stack([np.cos(w * t0), -np.sin(w * t0), np.ones_like(t0)])
    coef, *_ = np.linalg.lstsq(design, xl, rcond=None)
    resid = xl - design @ coef
    n_eff = max(int(t.size * 2.0 * cut / fs), 4)
    sd = float(np.std(resid)) * math.sqrt(2.0 / n_eff)
    # referred to t = 0 (not t[0])
    return complex(coef[0], coef[1]) * np.exp(-1j * w * t[0]), sd, n_eff


def accel_drive_tone(accel, structure, clock: ClockLine | None, rig=None) -> tuple[list[Finding], dict]:
    """Each accelerometer channel's drive tone against the DIC acceleration A (2 pi f)^2 (module rules).

    ``accel``: AccelData (DAQ clock, m/s^2 as read); ``structure``: the sine fit (camera clock, mm);
    ``clock``: the camera-to-DAQ relation (offset and rate) when determined, else None (then the phase is not
    judged: an unknown offset turns it by 2 pi f offset). Returns (findings, evidence per channel)."""
    f = float(structure.frequency_hz)
    w = 2.0 * math.pi * f
    a_mm, psi = structure.params_ref[0], structure.params_ref[2]
    # DIC: Y'' = -A w^2 sin(w (t - t_ref) + psi) = Re(A w^2 exp(i (w t + phi0 + pi/2))), phi0 the phase about t=0
    phi0 = psi - w * structure.t_ref_s
    dic = a_mm * 1e-3 * w * w * np.exp(1j * (phi0 + math.pi / 2.0))
    t_cam = np.asarray(accel.t_s, float) if clock is None else clock.camera_s(accel.t_s)
    # the DIC amplitude's relative sigma (amplitude and frequency of the fit)
    sa, sf = (float(x) if np.isfinite(x) else 0.0 for x in structure.std[:2])
    rel_dic = math.hypot(sa / a_mm if a_mm else 0.0, 2.0 * sf / f if f else 0.0)
    units = getattr(accel, "source_units", ("m/s^2", "m/s^2"))
    factors = getattr(accel, "mps2_per_source_unit", (1.0, 1.0))
    unit_source = getattr(accel, "unit_source", "default")
    findings: list[Finding] = []
    evidence: dict = {}
    for k, (name, x) in enumerate((("upper", accel.upper_ms2), ("lower", accel.lower_ms2))):
        tone, sd, _ = drive_tone(t_cam, x, f)
        ratio = tone / dic
        mag = abs(ratio)
        sd_mag = math.hypot(sd / abs(dic), mag * rel_dic)
        phase = float(np.angle(ratio))
        evidence[name] = {"drive_tone_mps2": abs(tone), "dic_acceleration_mps2": abs(dic), "ratio": mag,
                          "ratio_std": sd_mag, "phase_rad": phase if clock is not None else None,
                          "unit_as_read": units[k], "mps2_per_unit": factors[k]}
        tol = AMPLITUDE_TOL + 3.0 * sd_mag
        if abs(mag - 1.0) > tol:
            findings.append(_unit_finding(name, {"ratio": mag, "ratio_std": sd_mag, "drive_tone_mps2": abs(tone),
                                                 "dic_acceleration_mps2": abs(dic)},
                                          unit=units[k], factor=factors[k], unit_source=unit_source, rig=rig))
        if clock is not None and abs(phase) > POLARITY_LIMIT_RAD and mag > 3.0 * sd_mag:
            findings.append(Finding(
                "accel_polarity",
                f"accelerometer {name} channel inverted: its drive tone at {f:.3f} Hz is {math.degrees(phase):+.0f} "
                f"deg from the structure's acceleration by DIC (expected 0: both plates ride on the structure): "
                f"the sensor is mounted upside down or its channel is wired reversed ({_channel_key(rig, name)}); "
                "impact signs on it are reversed",
                [_channel_key(rig, name)], {"channel": name, "phase_rad": phase, "ratio": mag}, "warn"))
    return findings, evidence


def _channel_key(rig, name: str) -> str:
    acc = getattr(rig, "accelerometers", None)
    if acc is not None and getattr(acc, "file", "") and str(acc.file).lower().endswith(".tdms"):
        return f"accelerometers.{name}_channel"
    return f"accelerometers.{name}_column"


def _unit_finding(name: str, amplitude: dict, *, unit: str, factor: float, unit_source: str, rig) -> Finding:
    """The accelerometer amplitude finding, naming the key (unit or sensitivity) the ratio points to;
    ``amplitude``: the channel's ``ratio`` (drive tone / DIC acceleration) and its ``ratio_std``, the
    ``drive_tone_mps2`` as read and the ``dic_acceleration_mps2``; ``factor``: m/s^2 per unit as read."""
    mag, sd = amplitude["ratio"], amplitude["ratio_std"]
    tone, dic = amplitude["drive_tone_mps2"], amplitude["dic_acceleration_mps2"]
    ev = {"channel": name, "ratio": mag, "ratio_std": sd, "drive_tone_mps2": tone, "dic_acceleration_mps2": dic,
          "unit_as_read": unit, "unit_source": unit_source}
    head = (f"accelerometer {name} channel: its drive tone is {tone:.3g} m/s^2 as read ({unit}), the structure's "
            f"acceleration by DIC A (2 pi f)^2 = {dic:.3g} m/s^2 (ratio {mag:.3f} +- {sd:.3f})")
    if abs(mag * G0 - 1.0) < AMPLITUDE_TOL and factor == 1.0:
        return Finding("accel_unit", f"{head}: the data are in g, read as m/s^2: set accelerometers.unit: g "
                       "(impact peaks and energies on this channel are 9.81x too small)", ["accelerometers.unit"],
                       {**ev, "likely_unit": "g"}, "warn")
    if abs(mag / G0 - 1.0) < AMPLITUDE_TOL and abs(factor - G0) < 1e-6:
        return Finding("accel_unit", f"{head}: the data are in m/s^2, read as g: accelerometers.unit (or the "
                       "channel's unit string) should be m/s^2", ["accelerometers.unit"],
                       {**ev, "likely_unit": "m/s^2"}, "warn")
    if unit in ("V", "mV"):
        sens = getattr(getattr(getattr(rig, "accelerometers", None), "sensitivity_mv_per_g", None), name, None)
        ev["likely_sensitivity_mv_per_g"] = None if sens is None else float(sens) / mag
        return Finding("accel_sensitivity", f"{head}: accelerometers.sensitivity_mv_per_g ({name}) disagrees"
                       + (f", likely {float(sens) / mag:.4g} mV/g, not {float(sens):g}" if sens else ""),
                       ["accelerometers.sensitivity_mv_per_g"], ev, "warn")
    return Finding("accel_amplitude", f"{head}: accelerometers.unit / sensitivity, or camera.mm_per_px, disagree "
                   "with the measurement", ["accelerometers.unit", "camera.mm_per_px"], ev, "warn")


def plate_attribution(dic_impacts: Sequence, accel_impacts: Sequence, clock: ClockLine | None, fps: float,
                      rig=None) -> tuple[Finding | None, dict]:
    """Each DIC impact's plate against the accelerometer channel that responds strongest at the same time
    (camera clock through ``clock``, the offset and rate; within 0.5 ms + one frame); swapped channels when at
    least :data:`SWAP_FRACTION` of at least :data:`SWAP_MIN_IMPACTS` pairs disagree. Returns (finding or None,
    evidence)."""
    if clock is None or not dic_impacts or not accel_impacts:
        return None, {"matched": 0, "reason": "clock offset not determined" if clock is None
                      else "no impacts to compare"}
    tol = 0.0005 + 1.0 / fps
    acc_t = np.atleast_1d(clock.camera_s([a.t_s for a in accel_impacts]))
    agree = disagree = 0
    ratios = []
    for imp in dic_impacts:
        if imp.t_s is None or imp.plate not in ("top", "bottom"):
            continue
        k = int(np.argmin(np.abs(acc_t - imp.t_s)))
        if abs(acc_t[k] - imp.t_s) > tol:
            continue
        a = accel_impacts[k]
        if a.plate == imp.plate:
            agree += 1
        else:
            disagree += 1
        hit_e, other_e = ((a.energy_upper, a.energy_lower) if imp.plate == "top" else (a.energy_lower, a.energy_upper))
        ratios.append(hit_e / other_e if other_e > 0 else math.inf)
    n = agree + disagree
    ev = {"matched": n, "agree": agree, "disagree": disagree,
          "median_energy_ratio_hit_plate_channel": float(np.median(ratios)) if ratios else None}
    if n >= SWAP_MIN_IMPACTS and disagree >= SWAP_FRACTION * n:
        keys = [_channel_key(rig, "upper"), _channel_key(rig, "lower")]
        msg = (f"accelerometer channels swapped: for {disagree} of {n} impacts the channel that responds "
               f"strongest is the other plate's (DIC sees the ball hit the {'/'.join(['top', 'bottom'])} plate; the "
               f"channel named for that plate gets {ev['median_energy_ratio_hit_plate_channel']:.2g}x the other's "
               f"energy, median): exchange {keys[0]} and {keys[1]} in rig.yaml; until then every accelerometer "
               "impact is attributed to the wrong plate")
        return Finding("accel_channels_swapped", msg, keys, ev, "warn"), ev
    return None, ev


def tracking_check(track) -> Finding | None:
    """A body (ball, structure) lost in more than half the frames of ``track`` (:mod:`vibro_io.track_loss`): the
    refusal ``vibro analyze`` gives its own tracking, for a track read from dic.csv or DicFrames; else None."""
    losses = track_losses(track)
    message = lost_refusal(losses)
    if message is None:
        return None
    bad = [b for b in losses if b.refused()]
    return Finding("tracking", message, [k for b in bad for k in BODY_KEYS[b.name]],
                   {f"{b.name}_frames_lost": b.lost for b in bad} | {"frames": bad[0].frames}, "refuse")


def consistency_checks(ident, track, rig, accel=None, source: str = "the video") -> tuple[list[Finding], dict]:
    """Every cross-check of an identification (:class:`~vibro_fit.identify.Identification` of ``track`` with
    ``rig``, ``accel`` the AccelData or None): time base (step, drift), physical plausibility, accelerometer
    drive tone and plate attribution. Returns (findings, refusing ones first; evidence of the checks that
    passed too: {"time_base": .., "friction": .., "accelerometers": .., "plates": ..})."""
    from .plausibility import axis_gravity, friction_balance, physical_plausibility

    moves = ident.motion.structure_moves if ident.motion is not None else True
    out: list[Finding] = []
    evidence: dict = {}
    lost = tracking_check(track)
    if lost is not None:   # a body lost in most frames: refused, as vibro analyze refuses its own tracking
        out.append(lost)
    if moves:
        good = np.asarray(track.good, bool)
        scan = step_scan(np.asarray(track.t_s)[good], np.asarray(track.structure_mm)[good], ident.structure)
        if scan is not None:
            evidence["time_base"] = {"largest_step_s": scan["tau_s"], "largest_step_std_s": scan["tau_std_s"],
                                     "at_frame": int(np.asarray(track.frame)[good][scan["index"]]), "z": scan["z"]}
        step = time_base_step(track, ident.structure, float(rig.camera.fps), source)
        if step is not None:
            out.append(step)
        t = np.asarray(track.t_s, float)
        drift = time_base_drift(ident.rig_consistency, float(t[-1] - t[0]) if t.size else 0.0)
        if drift is not None:
            out.append(drift)
    flights = [f.model(ident.mass_kg, ident.g_axis_mps2) for f in ident.flights]
    out += physical_plausibility([i.model() for i in ident.impacts], flights, ident.structure, rig,
                                 ident.rig_consistency, moves,
                                 ident.drive.to_dict() if ident.drive is not None else None)
    axis = axis_gravity(ident.flights, g_axis_mps2=ident.g_axis_mps2, axis_tilt_deg=float(rig.setup.axis_tilt_deg),
                        noise_mm=ident.noise_mm, motion_state=ident.motion.state if ident.motion else None,
                        n_cor_impacts=sum(i.cor is not None and np.isfinite(i.cor) for i in ident.impacts))
    if axis is not None:   # the declared orientation contradicts the flights: named, refused
        out.append(axis)
    # the friction's dissipative part against its sigma and its physical floor, refused or not (below the
    # floor: zero within it, said here and nowhere claimed)
    friction = friction_balance(flights, float(rig.ball.mass_kg))
    if friction is not None:
        evidence["friction"] = friction
    if accel is not None and moves:
        off = ident.clock_offset
        clock = off.line if off is not None and off.known_offset_s is not None else None
        tone_findings, evidence["accelerometers"] = accel_drive_tone(accel, ident.structure, clock, rig)
        out += tone_findings
        if ident.accel is not None:
            swap, evidence["plates"] = plate_attribution(ident.impacts, ident.accel.impacts, clock,
                                                         float(rig.camera.fps), rig)
            if swap is not None:
                out.append(swap)
    return sorted(out, key=lambda f: not f.refuses), evidence


def consistency_section(findings: Sequence[Finding], evidence: dict | None = None) -> dict:
    """results.json ``consistency``: whether the results were withheld, every finding, the checks' numbers."""
    from .plausibility import _plain

    return {"refused": any(f.refuses for f in findings), "findings": [f.to_dict() for f in findings],
            "checks": _plain(dict(evidence or {}))}
