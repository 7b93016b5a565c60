"""The measured inputs of the discrepancy analysis, from the results sections and the DIC track.

Plain inputs only (no vibro_fit): the ``structure``, ``flights`` and ``impacts`` sections of
results.json (contract /shared/recording-format.md), a :class:`vibro_io.dictrack.DicTrack`
and the :class:`vibro_io.rig.RigConfig`. Everything here is SI (m, s, m/s) in the DIC frame:
ball and structure displacements since frame 0, positive up. The cavity centre sits on the
structure displacement; the ball centre minus the cavity centre is ``ball + c0`` minus it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_io.errors import RecordingError
from vibro_io.rig import RigConfig

from vibro_model.constants import G_MPS2 as G_MS2
MIN_FLIGHT_POINTS = 6


@dataclass(frozen=True)
class SineFit:
    """Y_s(t) = A sin(2 pi f t + phase) + B (m, s) as identified."""

    amplitude_m: float
    frequency_hz: float
    phase_rad: float
    offset_m: float


@dataclass
class FlightData:
    """One free flight: its DIC samples and the impacts that open/close it.

    ``t_ref_s`` is where the flight's state is referenced (the opening impact, else the first
    fitted frame); ``tau_s = t_s - t_ref_s``. ``open_impact``/``close_impact`` index
    :attr:`Measured.impacts` (None at the recording's ends). ``v_nominal`` gives the ball's
    velocity (m/s) at absolute times from the identified parabola (a start for the fits).
    """

    index: int
    t_ref_s: float
    t_end_s: float
    t_s: np.ndarray
    y_m: np.ndarray
    direction: str
    abc: tuple[float, float, float]
    open_impact: int | None = None
    close_impact: int | None = None

    @property
    def tau_s(self) -> np.ndarray:
        return self.t_s - self.t_ref_s

    def v_nominal(self, t_s):
        a, b, _ = self.abc
        return (2.0 * a * np.asarray(t_s, dtype=float) + b) * 1e-3


@dataclass
class ImpactData:
    """One identified impact (times s, velocities m/s) and its neighbouring flights (indices into
    :attr:`Measured.flights`, None when that flight was not usable)."""

    index: int
    t_s: float
    plate: str
    cor: float
    cor_std: float
    v_ball_before: float
    v_ball_after: float
    v_structure: float
    flight_before: int | None = None
    flight_after: int | None = None

    @property
    def speed_ms(self) -> float:
        """|relative impact speed| before the impact (m/s)."""
        return abs(self.v_ball_before - self.v_structure)


@dataclass
class Measured:
    """Everything the analysis uses, SI units, DIC frame."""

    sine: SineFit
    flights: list[FlightData]
    impacts: list[ImpactData]
    t_s: np.ndarray            # good track frames
    ball_m: np.ndarray
    structure_m: np.ndarray
    mass_kg: float
    free_play_m: float
    g_ms2: float = G_MS2
    notes: list[str] = field(default_factory=list)

    @property
    def t_first_s(self) -> float:
        return float(self.t_s[0])

    @property
    def t_last_s(self) -> float:
        return float(self.t_s[-1])


def _num(section: str, row: Mapping[str, Any], key: str, where: str, allow_none: bool = False) -> float | None:
    if not isinstance(row, Mapping):
        raise RecordingError(f"results {section}{where}: expected a mapping, got {type(row).__name__}")
    if key not in row:
        raise RecordingError(f"results {section}{where}: missing key '{key}'")
    value = row[key]
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise RecordingError(f"results {section}{where}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def parse_sine(structure: Mapping[str, Any]) -> SineFit:
    """The structure section (mm, Hz, rad) -> :class:`SineFit` (SI)."""
    a = _num("structure", structure, "amplitude_mm", "")
    f = _num("structure", structure, "frequency_hz", "")
    p = _num("structure", structure, "phase_rad", "")
    b = _num("structure", structure, "offset_mm", "")
    if f <= 0:
        raise RecordingError(f"results structure: 'frequency_hz' must be > 0, got {f}")
    return SineFit(abs(a) * 1e-3, f, p if a >= 0 else p + math.pi, b * 1e-3)


def _check_track(track: DicTrack) -> np.ndarray:
    if not isinstance(track, DicTrack):
        raise RecordingError(f"discrepancy: expected a DicTrack, got {type(track).__name__}")
    good = np.asarray(track.good, dtype=bool) & np.isfinite(track.structure_mm)
    if good.sum() < 20:
        raise RecordingError(f"DIC track: only {int(good.sum())} usable frames, the discrepancy analysis needs 20")
    t = np.asarray(track.t_s, dtype=float)[good]
    if np.any(np.diff(t) <= 0):
        raise RecordingError("DIC track: frame times do not increase")
    return good


def measured_from_sections(sections: Mapping[str, Any], track: DicTrack, rig: RigConfig) -> Measured:
    """Build :class:`Measured` from results sections (``structure``, ``flights``, ``impacts``),
    the DIC track and the rig. Raises :class:`RecordingError` naming the bad key/row."""
    if not isinstance(sections, Mapping):
        raise RecordingError("discrepancy: results sections must be a mapping")
    for key in ("structure", "flights", "impacts"):
        if key not in sections:
            raise RecordingError(f"results: missing section '{key}'")
    sine = parse_sine(sections["structure"])
    good = _check_track(track)
    t_all = np.asarray(track.t_s, dtype=float)
    ball_all = np.asarray(track.ball_mm, dtype=float) * 1e-3
    t, ball = t_all[good], ball_all[good]
    struct = np.asarray(track.structure_mm, dtype=float)[good] * 1e-3

    impacts: list[ImpactData] = []
    rows = sections["impacts"]
    if not isinstance(rows, Sequence):
        raise RecordingError("results impacts: expected a list")
    for k, row in enumerate(rows):
        where = f"[{k}]"
        plate = row.get("plate") if isinstance(row, Mapping) else None
        if plate not in ("top", "bottom"):
            raise RecordingError(f"results impacts{where}: 'plate' must be 'top' or 'bottom', got {plate!r}")
        cor = _num("impacts", row, "cor", where, allow_none=True)
        vals = [_num("impacts", row, key, where, allow_none=True)
                for key in ("t", "v_ball_before", "v_ball_after", "v_structure")]
        if cor is None or any(v is None for v in vals):
            continue  # an impact the identification could not measure
        std = row.get("cor_std")
        std = float(std) if isinstance(std, (int, float)) and not isinstance(std, bool) and math.isfinite(std) else 0.0
        impacts.append(ImpactData(len(impacts), vals[0], plate, cor, std, vals[1], vals[2], vals[3]))
    impacts.sort(key=lambda i: i.t_s)
    for j, imp in enumerate(impacts):
        imp.index = j
    times = np.array([i.t_s for i in impacts])

    def impact_at(tx: float) -> int | None:
        if times.size == 0:
            return None
        j = int(np.argmin(np.abs(times - tx)))
        return j if abs(times[j] - tx) < 1e-7 else None

    flights: list[FlightData] = []
    rows = sections["flights"]
    if not isinstance(rows, Sequence):
        raise RecordingError("results flights: expected a list")
    for k, row in enumerate(rows):
        where = f"[{k}]"
        if isinstance(row, Mapping) and (row.get("free") is False or row.get("friction_n", 0.0) is None):
            continue  # not a free flight: the identification could not fit it
        t0 = _num("flights", row, "t_start", where)
        t1 = _num("flights", row, "t_end", where)
        a, b, c = (_num("flights", row, key, where) for key in ("a", "b", "c"))
        direction = row.get("direction")
        if direction not in ("up", "down"):
            raise RecordingError(f"results flights{where}: 'direction' must be 'up' or 'down', got {direction!r}")
        if t1 <= t0:
            raise RecordingError(f"results flights{where}: t_end {t1} must exceed t_start {t0}")
        lo = row.get("t_first_frame", t0)
        hi = row.get("t_last_frame", t1)
        lo = float(lo) if isinstance(lo, (int, float)) and lo is not None else t0
        hi = float(hi) if isinstance(hi, (int, float)) and hi is not None else t1
        sel = (t >= max(lo, t0) - 1e-9) & (t <= min(hi, t1) + 1e-9) & (t > t0) & (t < t1)
        if sel.sum() < MIN_FLIGHT_POINTS:
            continue
        oi, ci = impact_at(t0), impact_at(t1)
        t_ref = t0 if oi is not None else float(t[sel][0])
        flights.append(FlightData(len(flights), t_ref, t1, t[sel], ball[sel], direction, (a, b, c), oi, ci))
    for fi, fl in enumerate(flights):
        if fl.open_impact is not None:
            impacts[fl.open_impact].flight_after = fi
        if fl.close_impact is not None:
            impacts[fl.close_impact].flight_before = fi
    notes = []
    if len(flights) < 3:
        notes.append(f"only {len(flights)} usable free flights")
    return Measured(sine, flights, impacts, t, ball, struct, float(rig.ball.mass_kg), 1e-3 * float(rig.free_play_mm),
                    notes=notes)


def difference_sigma(segments, order: int = 3) -> float:
    """White-noise sigma from ``order``-th differences of consecutive, evenly spaced samples, pooled
    over ``segments`` [(t_s, y), ...]: var(d_n) = C(2n, n) sigma^2 for white noise, while a smooth
    trajectory contributes only |y^(n)| dt^n (for a ball flight jerk dt^3 ~ 1e-8 m at 1000 fps; for the
    22 Hz structure A w^5 dt^5 ~ 0.07 um with order 5). Robust (MAD). NaN if fewer than 5 differences."""
    coef = np.array([(-1) ** (order - j) * math.comb(order, j) for j in range(order + 1)], dtype=float)
    pooled = []
    for t_s, y in segments:
        t = np.asarray(t_s, dtype=float)
        y = np.asarray(y, dtype=float)
        if t.size < order + 2:
            continue
        dt = np.diff(t)
        h = np.median(dt)
        even = np.abs(dt - h) < 0.01 * h
        ok = np.ones(t.size - order, dtype=bool)
        for j in range(order):
            ok &= even[j:j + t.size - order]
        d = sum(c * y[j:j + t.size - order] for j, c in enumerate(coef))
        pooled.append(d[ok])
    d = np.concatenate(pooled) if pooled else np.zeros(0)
    if d.size < 5:
        return float("nan")
    mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    return mad / math.sqrt(math.comb(2 * order, order))
