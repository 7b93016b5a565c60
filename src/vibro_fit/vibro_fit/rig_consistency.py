"""Is the rig description (rig.yaml) consistent with what the recording measures?

Three measured quantities can contradict rig.yaml:
- the free play b (half the ball's travel between the plates, from the impacts' relative positions) vs
  ``(structure.gap_mm - ball.diameter_mm) / 2``: ratio k_b;
- the flights' free-fall acceleration (mean of the up and down flights' median 2a, so that a friction
  opposing the motion cancels) vs the gravity along the axis as mounted, g cos(setup.axis_tilt_deg): ratio k_a
  (its std includes the declared tilt's own uncertainty, ``TILT_STD_DEG``: tan(theta) d(theta); on an axis
  within ``FALL_MIN_COS`` of horizontal the flights barely fall and k_a is not measured);
- the structure frequency on the camera clock vs ``excitation.frequency_hz`` and, with accelerometers,
  vs the excitation frequency on the DAQ clock (the accelerometers ride on the plates).

How they tell the keys apart:
- a wrong ``camera.mm_per_px`` scales every length: k_b and k_a equal (within their uncertainties);
- a wrong ``structure.gap_mm`` / ``ball.diameter_mm`` changes k_b only (flights still fall at g);
- a gravity tilt or a friction is physics, not a rig error: k_a < 1 with k_b = 1 (nothing reported here:
  the discrepancy analysis names it);
- a wrong ``camera.fps`` scales every time: the structure frequency differs from the nominal and from the
  DAQ clock's by the same factor r, and accelerations by r^2;
- a wrong ``excitation.frequency_hz`` alone: camera and DAQ clocks agree with each other, not with it.

Tolerances: 3 standard deviations of the measured ratios plus a floor (``GEOMETRY_TOL`` 2 % for the free
play, a rig's nominal dimensions are not exact; ``ACCEL_TOL`` 1 % for the acceleration; ``FREQ_TOL`` 5 %
for the nominal frequency, as the existing warning, and 0.5 % between the two clocks).
A statement with ``blocks_physics`` means no physics finding may be built on this identification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vibro_model.constants import G_MPS2

GEOMETRY_TOL = 0.02
ACCEL_TOL = 0.01
FREQ_TOL = 0.05
CLOCK_TOL = 0.005
N_SIGMA = 3.0
#: how well a rig's mounted tilt (rig.yaml setup.axis_tilt_deg) is known (deg, 1 sigma): g cos(theta) is then
#: known to g sin(theta) d(theta), 1.7 % of g cos(theta) per degree at 45 deg
TILT_STD_DEG = 1.0
#: below this cos(theta) (theta > 84 deg) the gravity along the axis is too small to test the scale with
FALL_MIN_COS = 0.1


@dataclass
class RigStatement:
    """One inconsistency between rig.yaml and the measurement."""

    keys: list[str]
    message: str
    measured: dict = field(default_factory=dict)
    suggested: dict = field(default_factory=dict)
    blocks_physics: bool = True

    def to_dict(self) -> dict:
        return {"keys": list(self.keys), "message": self.message, "measured": dict(self.measured),
                "suggested": dict(self.suggested), "blocks_physics": bool(self.blocks_physics)}


def free_play_ratio(impacts, free_play_rig_mm: float, noise_mm: float) -> tuple[float, float] | None:
    """(k_b, std) = measured free play / rig free play, from the impacts' relative positions (both plates
    needed, each plate level the median of its impacts; std from their robust scatter / sqrt(n))."""
    parts = {}
    for plate in ("top", "bottom"):
        y = np.array([i.y_rel_mm for i in impacts if i.plate == plate and np.isfinite(i.y_rel_mm)])
        if y.size == 0:
            return None
        sd = 1.4826 * float(np.median(np.abs(y - np.median(y)))) if y.size > 2 else float(np.ptp(y))
        sd = max(sd, noise_mm)
        parts[plate] = (float(np.median(y)), sd * math.sqrt(math.pi / 2.0) / math.sqrt(y.size))
    b = 0.5 * (parts["top"][0] - parts["bottom"][0])
    sb = 0.5 * math.hypot(parts["top"][1], parts["bottom"][1])
    return b / free_play_rig_mm, sb / free_play_rig_mm


def fall_ratio(flights, g_mps2: float) -> tuple[float, float, int] | None:
    """(k_a, std, n) = |mean of the up and down flights' median acceleration| / g_mps2 over the free flights
    (one direction alone when the other has none); ``g_mps2`` the gravity along the axis as mounted, g cos(theta),
    whose uncertainty from the declared tilt (:data:`TILT_STD_DEG`) is in the std. None without free flights or
    on an axis within :data:`FALL_MIN_COS` of horizontal."""
    cos_t = min(float(g_mps2) / G_MPS2, 1.0)
    if cos_t < FALL_MIN_COS:
        return None
    meds, vars_ = [], []
    n = 0
    for d in ("up", "down"):
        a = np.array([f.acceleration_mps2 for f in flights if f.is_free and f.direction == d])
        if a.size == 0:
            continue
        n += a.size
        sd_fit = float(np.median([f.acceleration_std_mps2 for f in flights if f.is_free and f.direction == d]))
        spread = 1.4826 * float(np.median(np.abs(a - np.median(a)))) if a.size > 2 else sd_fit
        meds.append(float(np.median(a)))
        vars_.append((max(spread, sd_fit) ** 2) * (math.pi / 2.0) / a.size)
    if not meds:
        return None
    a_mean = float(np.mean(meds))
    sd = math.sqrt(sum(vars_)) / len(meds)
    tilt_rel = math.sqrt(max(1.0 - cos_t ** 2, 0.0)) / cos_t * math.radians(TILT_STD_DEG)   # 0 when vertical
    return abs(a_mean) / g_mps2, math.hypot(sd / g_mps2, tilt_rel), n


def excitation_on_daq_clock_hz(accel, nominal_hz: float) -> float | None:
    """Excitation frequency (Hz) on the DAQ clock: dominant frequency of the plate accelerometers' sum below
    4x the nominal (the excitation; impacts ring in kHz); None when the record is shorter than 3 periods."""
    from scipy.signal import butter, sosfiltfilt

    from .structure_fit import spectral_peak_hz

    t = np.asarray(accel.t_s, float)
    if t.size < 64 or t[-1] - t[0] < 3.0 / nominal_hz:
        return None
    fs = accel.sample_rate_hz
    cut = min(4.0 * nominal_hz, 0.4 * fs)
    sos = butter(4, cut, btype="lowpass", fs=fs, output="sos")
    up, lo = (sosfiltfilt(sos, c - c.mean()) for c in (np.asarray(accel.upper_ms2, float),
                                                         np.asarray(accel.lower_ms2, float)))
    # both plates carry the drive tone in phase; an inverted channel (its own finding, vibro_fit.cross_checks)
    # must not cancel it from the sum
    x = up + lo if float(up @ lo) >= 0.0 else up - lo
    step = max(int(fs / (10.0 * cut)), 1)
    return spectral_peak_hz(t[::step], x[::step])


def check_rig(rig, structure, structure_moves: bool, impacts, flights, noise_mm: float, g_mps2: float,
              daq_frequency_hz: float | None = None) -> list[RigStatement]:
    """Statements of inconsistency between rig.yaml and the measurement (see module rules)."""
    out: list[RigStatement] = []
    f_nom = rig.excitation.frequency_hz
    fps = rig.camera.fps
    time_scale = None  # camera time per true time, when a wrong fps is established
    fall = fall_ratio(flights, g_mps2)
    if structure_moves:
        f_cam = float(structure.frequency_hz)
        sf = float(structure.std[1]) if np.isfinite(structure.std[1]) else 0.0
        r_nom = f_cam / f_nom
        if daq_frequency_hz is not None and abs(f_cam / daq_frequency_hz - 1.0) > CLOCK_TOL + N_SIGMA * sf / f_cam:
            r = f_cam / daq_frequency_hz
            time_scale = 1.0 / r
            out.append(RigStatement(
                ["camera.fps"],
                f"camera.fps: the structure moves at {f_cam:.3f} Hz on the camera clock but the accelerometers "
                f"see the excitation at {daq_frequency_hz:.3f} Hz on theirs (ratio {r:.3f}): the frame times are "
                f"scaled; fps likely {fps / r:.4g}, not {fps:g}",
                {"structure_frequency_hz": f_cam, "daq_excitation_frequency_hz": daq_frequency_hz},
                {"camera.fps": fps / r}))
        elif abs(r_nom - 1.0) > FREQ_TOL + N_SIGMA * sf / f_nom:
            if daq_frequency_hz is not None:
                out.append(RigStatement(
                    ["excitation.frequency_hz"],
                    f"excitation.frequency_hz: camera and accelerometer clocks agree on {f_cam:.3f} Hz, not the "
                    f"{f_nom:g} Hz of rig.yaml; the measured frequency is used",
                    {"structure_frequency_hz": f_cam, "daq_excitation_frequency_hz": daq_frequency_hz},
                    {"excitation.frequency_hz": f_cam}, blocks_physics=False))
            else:
                fall_words = ""
                keys = ["camera.fps", "excitation.frequency_hz"]
                if fall is not None and fall[2] >= 3:
                    fall_words = (f"; flights fall at {fall[0] * g_mps2:.2f} m/s^2 "
                                  f"({fall[0]:.3f} g, a time scale of {r_nom:.3f} gives {r_nom ** 2:.3f} g)")
                    if abs(fall[0] - r_nom ** 2) <= N_SIGMA * fall[1] + 0.05 * r_nom ** 2:
                        keys = ["camera.fps"]
                        time_scale = 1.0 / r_nom
                near = min((0.25, 0.5, 2.0, 4.0), key=lambda q: abs(math.log(r_nom / q)))
                simple = abs(r_nom / near - 1.0) < 0.01
                what = (f"fps likely {fps / r_nom:.4g}, not {fps:g}" if keys == ["camera.fps"] else
                        f"{'camera.fps (likely ' + format(fps / r_nom, '.4g') + ', not ' + format(fps, 'g') + ')'} "
                        f"or excitation.frequency_hz")
                ratio_words = f" ({'x' + format(near, 'g') if simple else 'ratio ' + format(r_nom, '.3f')})"
                out.append(RigStatement(
                    keys,
                    f"{' / '.join(keys)}: the structure moves at {f_cam:.3f} Hz on the camera clock vs "
                    f"excitation.frequency_hz {f_nom:g} Hz{ratio_words}{fall_words}: {what}",
                    {"structure_frequency_hz": f_cam, "frequency_ratio": r_nom,
                     **({"fall_acceleration_mps2": fall[0] * g_mps2} if fall else {})},
                    {"camera.fps": fps / r_nom}))
    if time_scale is not None:
        return out  # every length-per-time ratio below is scaled by the wrong clock: no further test
    free = free_play_ratio(impacts, rig.free_play_mm, noise_mm)
    if free is None:
        return out
    kb, skb = free
    if abs(kb - 1.0) <= GEOMETRY_TOL + N_SIGMA * skb:
        return out
    b_meas, b_rig = kb * rig.free_play_mm, rig.free_play_mm
    free_words = (f"free play measures {b_meas:.3f} mm vs {b_rig:.3f} mm from rig.yaml "
                  "((gap_mm - diameter_mm) / 2)")
    measured = {"free_play_mm": b_meas, "free_play_rig_mm": b_rig, "free_play_ratio": kb}
    if fall is None:
        out.append(RigStatement(
            ["camera.mm_per_px", "structure.gap_mm", "ball.diameter_mm"],
            f"camera.mm_per_px or structure.gap_mm / ball.diameter_mm: {free_words}; no free flight to tell a "
            f"scale error (which would also change the fall acceleration) from a wrong gap or diameter",
            measured))
        return out
    ka, ska, _ = fall
    measured.update({"fall_acceleration_mps2": ka * g_mps2, "fall_ratio": ka})
    fall_words = f"flights fall at {ka * g_mps2:.2f} m/s^2 ({ka:.3f} g)"
    if abs(ka - kb) <= N_SIGMA * math.hypot(ska, skb) + ACCEL_TOL + GEOMETRY_TOL:
        k = (ka / ska ** 2 + kb / skb ** 2) / (1 / ska ** 2 + 1 / skb ** 2) if ska > 0 and skb > 0 else kb
        mm = rig.camera.mm_per_px
        out.append(RigStatement(
            ["camera.mm_per_px"],
            f"camera.mm_per_px: {fall_words} and {free_words}: every length is {k:.3f} x the truth, "
            f"scale likely {mm / k:.4g}, not {mm:g}", measured, {"camera.mm_per_px": mm / k}))
    elif abs(ka - 1.0) <= N_SIGMA * ska + ACCEL_TOL:
        out.append(RigStatement(
            ["structure.gap_mm", "ball.diameter_mm"],
            f"structure.gap_mm / ball.diameter_mm: {free_words}, while {fall_words} (the image scale is right): "
            f"gap - diameter likely {2 * b_meas:.3f} mm, not {2 * b_rig:.3f} mm", measured,
            {"gap_minus_diameter_mm": 2 * b_meas}))
    else:
        out.append(RigStatement(
            ["camera.mm_per_px", "structure.gap_mm", "ball.diameter_mm"],
            f"camera.mm_per_px or structure.gap_mm / ball.diameter_mm: {free_words} and {fall_words}, "
            "which no single scale error explains (a scale error changes both by the same factor)", measured))
    return out
