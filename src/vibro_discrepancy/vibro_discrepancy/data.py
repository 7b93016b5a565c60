"""The measured inputs of the discrepancy analysis: the identified motion (domain model) and the DIC track.

Input: the identification as :mod:`vibro_model.results` types (:class:`StructureMotion`, :class:`Flight`,
:class:`Impact`, or the whole :class:`ResultsDocument`), a :class:`vibro_io.dictrack.DicTrack` and the
:class:`vibro_io.rig.RigConfig`; no vibro_fit. Everything here is SI (m, s, m/s) in the DIC frame: ball and
structure displacements since frame 0, positive up (the track's mm are converted here, at the edge). The
cavity centre sits on the structure displacement; the ball centre minus the cavity centre is ``ball + c0``
minus it. :func:`measured_from_sections` reads a results.json-shaped mapping (a file read from disk, a
test's hand-made input) into the model types first, validating every key. The identification's verdict on the
drive (results.json ``drive``, :mod:`vibro_fit.drive`) travels along as plain JSON (:attr:`Measured.drive`): a
drive that did not hold still is not a structure tone (:func:`drive_change`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Mapping, Sequence

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_io.plate_motion import PlateCreep, plate_creeps
from vibro_io.rig import RigConfig
from vibro_model.codec import Fields
from vibro_model.constants import G_MPS2
from vibro_model.drive_envelope import DriveEnvelope
from vibro_model.errors import RecordingError
from vibro_model.results import Flight, Impact, ResultsDocument, StructureMotion
from vibro_model.units import mm_to_m

MIN_FLIGHT_POINTS = 6
#: an impact's time and a flight's start/end name the same event when they agree this well (s)
SAME_TIME_S = 1e-7


@dataclass(kw_only=True)
class FlightSamples:
    """One free flight of the identification (``flight``) with its DIC samples and the impacts that
    open/close it.

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
    flight: Flight
    open_impact: int | None = None
    close_impact: int | None = None

    @property
    def tau_s(self) -> np.ndarray:
        return self.t_s - self.t_ref_s

    def v_nominal(self, t_s):
        """dY_b/dt (m/s) of the identified parabola Y_b = a t^2 + b t + c at absolute times ``t_s`` (s)."""
        return 2.0 * self.flight.a_mps2 * np.asarray(t_s, dtype=float) + self.flight.b_mps


@dataclass(kw_only=True)
class Measured:
    """Everything the analysis uses, SI units, DIC frame.

    ``structure``: the identified sine (amplitude >= 0); ``impacts``: the identified impacts the analysis
    can use (COR, time and velocities known), in time order and renumbered: ``index`` is the position
    in this list, ``flight_before``/``flight_after`` index :attr:`flights` (None: no usable flight), an
    unknown ``cor_std`` is 0."""

    structure: StructureMotion
    flights: list[FlightSamples]
    impacts: list[Impact]
    t_s: np.ndarray            # good track frames
    ball_m: np.ndarray
    structure_m: np.ndarray
    mass_kg: float
    free_play_m: float
    scale_rel_std: float = 0.0  # rig.yaml camera.mm_per_px_rel_std (0: not given)
    calibrated: bool = False    # rig.yaml names a camera calibration (camera.calibration): positions undistorted
    g_mps2: float = G_MPS2      # gravity along the motion axis as declared, g cos(rig.yaml setup.axis_tilt_deg)
    axis_tilt_deg: float = 0.0  # rig.yaml setup.axis_tilt_deg: the axis' declared tilt from vertical (deg)
    notes: list[str] = field(default_factory=list)
    drive: Mapping[str, Any] | None = None   # results.json ``drive`` (the identification's windowed drive)
    plate_creeps: Mapping[str, PlateCreep] = field(default_factory=dict)   # plates creeping, in the CORs

    @cached_property
    def drive_envelope(self) -> DriveEnvelope | None:
        """The drive as it moved over the take (:class:`vibro_model.drive_envelope.DriveEnvelope` of the
        ``drive`` section against the identified sine), None where it held still or was not tested. The
        discrepancy models' structure is their fitted sine under it (:attr:`.model.FittedModel.motion`), and
        their harmonics are fitted on the track without it (:meth:`DriveEnvelope.demodulated`): a drive that
        moved is neither a COR law nor a harmonic. A frequency drift of 0.02 Hz/s over 8 s gave D_r 2.3 % with
        the sine alone and a COR law claimed from its miss (e(0) = 1.03); 0.048 % under the envelope, nothing
        claimed. A 10 % amplitude step within 0.1 s on a horizontal rig with guide-rod friction: a COR law
        claimed from the COR step the sine's miss made at the drive's step; under the envelope only the
        friction. Parsed once per measurement (every model fitted to it asks)."""
        try:
            return DriveEnvelope.of_drive_section(self.drive, float(self.structure.offset_m or 0.0))
        except ValueError:
            return None

    def plate_velocity_mps(self, plate: str, t_s: float) -> float:
        """How much faster than the tracked structure ``plate`` moves at ``t_s`` (m/s): the creep the
        identification took into its CORs (results.json ``plate_motion``), 0 for a plate that does not creep."""
        creep = self.plate_creeps.get(plate)
        return creep.velocity_mps(t_s) if creep is not None else 0.0

    @property
    def frequency_hz(self) -> float:
        """The identified drive frequency (Hz)."""
        return float(self.structure.frequency_hz)

    @property
    def t_first_s(self) -> float:
        return float(self.t_s[0])

    @property
    def t_last_s(self) -> float:
        return float(self.t_s[-1])


def speed_mps(impact: Impact) -> float:
    """|relative impact speed| before the impact (m/s)."""
    return abs(impact.v_ball_before_mps - impact.v_structure_mps)


def _sine(structure: StructureMotion | None) -> StructureMotion:
    """The identified sine, checked (every parameter known, f > 0) and with amplitude >= 0."""
    if not isinstance(structure, StructureMotion):
        raise RecordingError(f"discrepancy: expected the identified structure motion, got {type(structure).__name__}")
    unknown = [k for k in ("amplitude_m", "frequency_hz", "phase_rad", "offset_m") if getattr(structure, k) is None]
    if unknown:
        raise RecordingError(f"results structure: {', '.join(unknown)} unknown (the structure sine is needed)")
    if structure.frequency_hz <= 0:
        raise RecordingError(f"results structure: 'frequency_hz' must be > 0, got {structure.frequency_hz}")
    if structure.amplitude_m >= 0:
        return structure
    return replace(structure, amplitude_m=-structure.amplitude_m, phase_rad=structure.phase_rad + math.pi)


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


def usable_impacts(impacts: Sequence[Impact]) -> list[Impact]:
    """The impacts the identification measured (COR, time and velocities known), in time order and
    renumbered (``index`` = position), links cleared, unknown ``cor_std`` as 0."""
    known = [i for i in impacts if None not in (i.cor, i.t_s, i.v_ball_before_mps, i.v_ball_after_mps,
                                               i.v_structure_mps)]
    known.sort(key=lambda i: i.t_s)
    return [replace(i, index=j, cor_std=0.0 if i.cor_std is None else i.cor_std, flight_before=None,
                    flight_after=None) for j, i in enumerate(known)]


def _flight_samples(k: int, fl: Flight, t: np.ndarray, ball: np.ndarray, impact_times: np.ndarray
                    ) -> FlightSamples | None:
    """Flight row ``k`` with its DIC samples (None: not free, or fewer than MIN_FLIGHT_POINTS frames)."""
    if not fl.free or fl.friction_n is None:
        return None  # not a free flight: the identification could not fit it
    where = f"results flights[{k}]"
    unknown = [name for name, v in (("t_start", fl.t_start_s), ("t_end", fl.t_end_s), ("a", fl.a_mps2),
                                    ("b", fl.b_mps), ("c", fl.c_m)) if v is None]
    if unknown:
        raise RecordingError(f"{where}: {', '.join(unknown)} unknown in a free flight")
    direction = fl.direction or "up"  # as the contract writes a flight without a direction
    if direction not in ("up", "down"):
        raise RecordingError(f"{where}: 'direction' must be 'up' or 'down', got {direction!r}")
    t0, t1 = fl.t_start_s, fl.t_end_s
    if t1 <= t0:
        raise RecordingError(f"{where}: t_end {t1} must exceed t_start {t0}")
    lo = t0 if fl.t_first_frame_s is None else fl.t_first_frame_s
    hi = t1 if fl.t_last_frame_s is None else fl.t_last_frame_s

    def impact_at(tx: float) -> int | None:
        if impact_times.size == 0:
            return None
        j = int(np.argmin(np.abs(impact_times - tx)))
        return j if abs(impact_times[j] - tx) < SAME_TIME_S else None

    oi, ci = impact_at(t0), impact_at(t1)
    # a frame at an impact's time is contact, not flight; a flight's end that is no impact is the recording's
    # first or last frame, free (the identification fitted it): kept, or a take's last flight loses a frame
    # and, short, its impact is left to the paper's Eq. 16 under an effect that biases it
    opens = t > t0 if oi is not None else t >= t0 - 1e-9
    closes = t < t1 if ci is not None else t <= t1 + 1e-9
    sel = (t >= max(lo, t0) - 1e-9) & (t <= min(hi, t1) + 1e-9) & opens & closes
    if sel.sum() < MIN_FLIGHT_POINTS:
        return None
    t_ref = t0 if oi is not None else float(t[sel][0])
    return FlightSamples(index=-1, t_ref_s=t_ref, t_end_s=t1, t_s=t[sel], y_m=ball[sel], direction=direction,
                         flight=fl, open_impact=oi, close_impact=ci)


def measured_from_model(structure: StructureMotion | None, flights: Sequence[Flight], impacts: Sequence[Impact],
                        track: DicTrack, rig: RigConfig, drive: Mapping[str, Any] | None = None,
                        plate_motion: Mapping[str, Any] | None = None) -> Measured:
    """Build :class:`Measured` from the identification (model types), the DIC track and the rig (``drive``: the
    results' ``drive`` section, carried as it is; ``plate_motion``: its ``plate_motion`` section). Raises
    :class:`RecordingError` naming what is missing or
    inconsistent."""
    sine = _sine(structure)
    good = _check_track(track)
    t = np.asarray(track.t_s, dtype=float)[good]
    ball = mm_to_m(np.asarray(track.ball_mm, dtype=float)[good])
    struct = mm_to_m(np.asarray(track.structure_mm, dtype=float)[good])
    usable = usable_impacts(impacts)
    times = np.array([i.t_s for i in usable])
    samples = [s for k, fl in enumerate(flights) if (s := _flight_samples(k, fl, t, ball, times)) is not None]
    links: dict[int, dict[str, int]] = {}
    for fi, fs in enumerate(samples):
        fs.index = fi
        if fs.open_impact is not None:
            links.setdefault(fs.open_impact, {})["flight_after"] = fi
        if fs.close_impact is not None:
            links.setdefault(fs.close_impact, {})["flight_before"] = fi
    usable = [replace(i, **links.get(j, {})) for j, i in enumerate(usable)]
    notes = [f"only {len(samples)} usable free flights"] if len(samples) < 3 else []
    return Measured(structure=sine, flights=samples, impacts=usable, t_s=t, ball_m=ball, structure_m=struct,
                    mass_kg=float(rig.ball.mass_kg), free_play_m=mm_to_m(float(rig.free_play_mm)), notes=notes,
                    scale_rel_std=float(rig.camera.mm_per_px_rel_std or 0.0),
                    calibrated=getattr(rig.camera, "calibration", None) is not None, g_mps2=float(rig.g_axis_mps2),
                    axis_tilt_deg=float(rig.setup.axis_tilt_deg),
                    drive=_drive_section(drive), plate_creeps=plate_creeps(plate_motion))


def measured_from_document(doc: ResultsDocument, track: DicTrack, rig: RigConfig) -> Measured:
    """:func:`measured_from_model` of a results document's structure, flights and impacts."""
    if not isinstance(doc, ResultsDocument):
        raise RecordingError(f"discrepancy: expected a ResultsDocument, got {type(doc).__name__}")
    return measured_from_model(doc.structure, doc.flights, doc.impacts, track, rig, doc.sections.get("drive"),
                               doc.sections.get("plate_motion"))


def sections_model(sections: Mapping[str, Any]) -> tuple[StructureMotion, list[Flight], list[Impact]]:
    """(structure, flights, impacts) of a results.json-shaped mapping (``structure``, ``flights``,
    ``impacts`` as the contract writes them), validated by the codec (errors name the key and row)."""
    if not isinstance(sections, Mapping):
        raise RecordingError("discrepancy: results sections must be a mapping")
    for key in ("structure", "flights", "impacts"):
        if key not in sections:
            raise RecordingError(f"results: missing section '{key}'")
    f = Fields(sections, "results")
    return (StructureMotion.from_dict(sections["structure"], "results.structure"),
            [Flight.from_dict(r.data, r.where) for r in f.rows("flights")],
            [Impact.from_dict(r.data, r.where) for r in f.rows("impacts")])


def measured_from_sections(sections: Mapping[str, Any], track: DicTrack, rig: RigConfig) -> Measured:
    """:func:`measured_from_model` of a results.json-shaped mapping (read by :func:`sections_model`)."""
    return measured_from_model(*sections_model(sections), track, rig, sections.get("drive"),
                               sections.get("plate_motion"))


def _drive_section(drive: Any) -> Mapping[str, Any] | None:
    """The ``drive`` section when it is a mapping (else None: older results have none)."""
    return drive if isinstance(drive, Mapping) else None


def drive_change(meas: Measured) -> Mapping[str, Any] | None:
    """The ``drive`` section when the identification found the drive not stationary (``stationary`` false), else
    None (stationary, not tested, or no section)."""
    d = meas.drive
    return d if d is not None and d.get("stationary") is False else None


def drive_change_words(drive: Mapping[str, Any]) -> str:
    """What the drive did, in words (the section's own, else a generic line)."""
    words = drive.get("words")
    return str(words) if words else "the drive is not stationary (results.json drive)"


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


def measurement_of(identified: ResultsDocument | Mapping[str, Any], track: DicTrack, rig: RigConfig) -> Measured:
    """:class:`Measured` of the identification: a :class:`ResultsDocument` as it is, a results.json-shaped
    mapping through :func:`measured_from_sections`."""
    if isinstance(identified, ResultsDocument):
        return measured_from_document(identified, track, rig)
    return measured_from_sections(identified, track, rig)
