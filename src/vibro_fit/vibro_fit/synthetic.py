"""Analytic reference motion for tests and benchmarks (independent of vibro_sim).

A ball between two plates of a structure moving as Y_s = A sin(2 pi f t + phi) + B (SI units). Between
impacts the ball has a constant acceleration per flight (-g plus a constant force per flight, chosen by
the sign of the relative velocity at take-off), so every flight is an exact parabola and every impact is
exact: instants are found with brentq on y_b - y_s = +-b, velocities updated with
v_b+ = v_s - e (v_b- - v_s).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq

from vibro_io.accel import AccelData
from vibro_io.dictrack import DicTrack
from vibro_io.rig import parse_rig
from vibro_model.constants import G_MPS2
from vibro_model.results import Impact, StructureMotion
from vibro_model.units import m_to_mm


@dataclass
class Truth:
    """Piecewise-parabolic ball motion; ``pieces`` = (t0, y0_m, v0_mps, a_mps2) per flight; the structure's
    exact sine as the model type (SI)."""

    structure: StructureMotion
    free_play_m: float
    pieces: list[tuple[float, float, float, float]]
    impacts: list[Impact]          # exact: no stds; impact k ends flight k
    flight_accel_mps2: list[float]

    def structure_m(self, t):
        s = self.structure
        return s.amplitude_m * np.sin(2 * np.pi * s.frequency_hz * np.asarray(t) + s.phase_rad) + s.offset_m

    def ball_m(self, t):
        t = np.asarray(t, float)
        starts = np.array([p[0] for p in self.pieces])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        p = np.array(self.pieces)[k]
        d = t - p[:, 0]
        return p[:, 1] + p[:, 2] * d + 0.5 * p[:, 3] * d * d


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """The simulated rig and motion (SI): the structure's sine (amplitude m, frequency Hz, phase rad), the free
    play (m), the plates' CORs, the duration (s), constant forces (N) on flights that start moving up
    (``force_up_n``, usually negative: friction opposes motion) or down relative to the structure, the ball's
    mass (kg), ``cor_jitter``: N(0, jitter) scatter of each impact's COR (``seed``), and the ball's start
    relative to the structure (m, m/s)."""

    amplitude_m: float = 5e-3
    frequency_hz: float = 22.0
    phase_rad: float = 0.3
    free_play_m: float = 5.915e-3
    cor_top: float = 0.6
    cor_bottom: float = 0.75
    duration_s: float = 1.6
    force_up_n: float = 0.0
    force_down_n: float = 0.0
    mass_kg: float = 1.82e-4
    cor_jitter: float = 0.0
    seed: int = 0
    y0_rel_m: float = 0.0
    v0_mps: float = 0.0


def simulate(scenario: Scenario | None = None, /, **overrides) -> Truth:
    """Event-driven exact simulation of ``scenario`` (default :class:`Scenario`) with the fields named in
    ``overrides`` replaced (e.g. ``simulate(amplitude_m=3e-3, duration_s=0.6)``)."""
    sc = replace(scenario or Scenario(), **overrides)
    amplitude_m, frequency_hz, phase_rad, free_play_m = sc.amplitude_m, sc.frequency_hz, sc.phase_rad, sc.free_play_m
    cor_top, cor_bottom, duration_s, mass_kg = sc.cor_top, sc.cor_bottom, sc.duration_s, sc.mass_kg
    force_up_n, force_down_n, cor_jitter = sc.force_up_n, sc.force_down_n, sc.cor_jitter
    y0_rel_m, v0_mps = sc.y0_rel_m, sc.v0_mps
    rng = np.random.default_rng(sc.seed)
    w = 2 * np.pi * frequency_hz
    A, ph, b = amplitude_m, phase_rad, free_play_m

    def ys(t):
        return A * np.sin(w * t + ph)

    def vs(t):
        return A * w * np.cos(w * t + ph)

    t0, y0, v0 = 0.0, ys(0.0) + y0_rel_m, vs(0.0) + v0_mps
    pieces, impacts, accs = [], [], []
    step = 2e-5
    while t0 < duration_s:
        up = (v0 - vs(t0)) > 0
        a = -G_MPS2 + (force_up_n if up else force_down_n) / mass_kg
        pieces.append((t0, y0, v0, a))
        accs.append(a)

        def rel(t):
            d = t - t0
            return y0 + v0 * d + 0.5 * a * d * d - ys(t)

        tt = t0 + step * np.arange(1, int((duration_s + 0.05 - t0) / step) + 2)
        r = rel(tt)
        hit = np.flatnonzero((r >= b) | (r <= -b))
        if hit.size == 0:
            break
        j = hit[0]
        plate = "top" if r[j] >= b else "bottom"
        target = b if plate == "top" else -b
        lo = tt[j - 1] if j > 0 else t0 + 1e-12
        ti = brentq(lambda t: rel(t) - target, lo, tt[j], xtol=1e-15)
        vb = v0 + a * (ti - t0)
        vst = vs(ti)
        e = (cor_top if plate == "top" else cor_bottom) + cor_jitter * rng.standard_normal()
        vb_after = vst - e * (vb - vst)
        impacts.append(Impact(index=len(impacts), t_s=ti, plate=plate, cor=float(e), cor_std=None,
                              v_ball_before_mps=float(vb), v_ball_after_mps=float(vb_after),
                              v_structure_mps=float(vst)))
        t0, y0, v0 = ti, ys(ti) + target, vb_after
        if abs(vb_after - vst) < 1e-3:
            break
    return Truth(StructureMotion(amplitude_m=A, frequency_hz=frequency_hz, phase_rad=ph, offset_m=0.0), b, pieces,
                 impacts, accs)


def sample_track(truth: Truth, fps: float = 1000.0, n_frames: int = 1500, t0_s: float = 0.0,
                 noise_mm: float = 0.0005, seed: int = 1, ball_offset_mm: float = 0.0) -> DicTrack:
    """A DicTrack (mm since frame 0, positive up) sampled from ``truth`` plus white noise (mm)."""
    rng = np.random.default_rng(seed)
    t = t0_s + np.arange(n_frames) / fps
    ball = m_to_mm(truth.ball_m(t))
    st = m_to_mm(truth.structure_m(t))
    ball = ball - ball[0] + noise_mm * rng.standard_normal(n_frames) + ball_offset_mm
    st = st - st[0] + noise_mm * rng.standard_normal(n_frames)
    n = n_frames
    return DicTrack(frame=np.arange(n), t_s=t, ball_mm=ball, structure_mm=st, ball_valid=np.full(n, 20),
                    structure_valid=np.full(n, 40), ball_zncc=np.full(n, 0.99), structure_zncc=np.full(n, 0.99),
                    lost=np.zeros(n, bool))


def paper_rig(frequency_hz: float = 22.0, fps: float = 1000.0, accelerometers: bool = False):
    """A RigConfig with the paper's ball and gap (b = 5.915 mm), for tests and benchmarks."""
    data = {
        "camera": {"fps": fps, "t0_s": 0.0, "mm_per_px": 0.05},
        "ball": {"mass_kg": 1.82e-4, "diameter_mm": 4.77, "youngs_modulus_pa": 3.1e11, "poisson_ratio": 0.27},
        "structure": {"gap_mm": 16.6, "mass_kg": 0.663, "youngs_modulus_pa": 7.0e10, "poisson_ratio": 0.33},
        "excitation": {"frequency_hz": frequency_hz},
        "dic": {"subset_px": 31, "mesh_step_px": 10, "ball_roi": [100, 100, 60, 60],
                "structure_roi": [10, 10, 60, 60]},
    }
    if accelerometers:
        data["accelerometers"] = {"file": "accel.csv", "time_column": "time_s", "upper_column": "upper_ms2",
                                  "lower_column": "lower_ms2"}
    return parse_rig(data, "synthetic rig.yaml")


@dataclass(frozen=True, kw_only=True)
class AccelSetup:
    """Synthetic accelerometers: sample rate (Hz), duration (s), DAQ clock minus camera clock (s), the two
    ringing modes (Hz), their amplitude (m/s^2) and decay time (s), the white noise (m/s^2, ``seed``), and the
    upper channel's clipping level (m/s^2; None: no clipping)."""

    fs_hz: float = 50_000.0
    duration_s: float = 1.5
    offset_s: float = 0.0
    ring_hz: tuple[float, float] = (3100.0, 7400.0)
    ring_mps2: float = 300.0
    tau_s: float = 0.002
    noise_mps2: float = 2.0
    seed: int = 2
    clip_mps2: float | None = None


def accel_signals(truth: Truth, setup: AccelSetup | None = None, /, **overrides):
    """Synthetic accelerometer samples (vibro_io AccelData) of ``setup`` (default :class:`AccelSetup`) with the
    fields named in ``overrides`` replaced: structure acceleration + a decaying two-mode ringing starting at
    each impact (stronger on the channel of the plate hit: x1 vs x0.3) + white noise. DAQ clock = camera
    clock + ``offset_s``."""
    st = replace(setup or AccelSetup(), **overrides)
    fs_hz, duration_s, offset_s, ring_hz, ring_mps2 = st.fs_hz, st.duration_s, st.offset_s, st.ring_hz, st.ring_mps2
    tau_s, noise_mps2, clip_mps2 = st.tau_s, st.noise_mps2, st.clip_mps2
    rng = np.random.default_rng(st.seed)
    t = np.arange(int(duration_s * fs_hz)) / fs_hz + offset_s
    tc = t - offset_s
    s = truth.structure
    w = 2 * np.pi * s.frequency_hz
    base = -s.amplitude_m * w * w * np.sin(w * tc + s.phase_rad)
    up = base + noise_mps2 * rng.standard_normal(t.size)
    lo = base + noise_mps2 * rng.standard_normal(t.size)
    for imp in truth.impacts:
        d = tc - imp.t_s
        m = d >= 0
        ring = np.zeros_like(t)
        ring[m] = ring_mps2 * np.exp(-d[m] / tau_s) * (np.sin(2 * np.pi * ring_hz[0] * d[m])
                                                      + 0.6 * np.sin(2 * np.pi * ring_hz[1] * d[m]))
        gu, gl = (1.0, 0.3) if imp.plate == "top" else (0.3, 1.0)
        up += gu * ring
        lo += gl * ring
    if clip_mps2 is not None:
        up = np.clip(up, -clip_mps2, clip_mps2)
    return AccelData(t, up, lo)
