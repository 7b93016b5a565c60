"""Out-of-catalogue effects of the synthetic rig: physics that no term of the discrepancy
library (vibro_discrepancy.library) models, so the analysis must report them as ``unexplained``
with where and what. They exist to test that; a lab recording may show any of them.

- ``cor_drift``: the COR drifts slowly over the recording (wear, heating of the contact): from frame 0
  on, e_i = law(i) + drift_per_s * (i - i0) / (2 f), i0 the first impact in the camera window: linear in
  the impact count, so in time at the rig's two impacts per cycle (t_i - t_i0 ~ (i - i0) / (2 f)); the
  lead-in runs with the law alone, so the regime is settled when the drift starts.
- ``structure_tone``: a second structure tone not at a harmonic of the drive (another mode, a beat):
  Y_s += tone_amplitude_um * sin(2 pi tone_frequency_hz t + tone_phase_rad) on both plates.
- ``plate_step``: the upper plate's height steps mid-recording (a loosening screw): at camera time
  ``step_time_s`` it backs off upwards by ``step_um``; the cavity grows, the lower plate and the
  tracked structure (the ROI sits on the lower plate) stay. The images draw the upper plate where it
  was (the step is about a pixel; DIC never tracks the upper plate).
- ``plate_creep``: the upper plate creeps over the take (a screw slowly backing off, a mount relaxing): its
  height against the tracked structure (the lower plate) changes by ``creep_um_per_s`` every second, at the
  rig's height at camera time 0 (lower before it, over the lead-in); the plate's velocity is the structure's plus
  the creep, so an impact on it meets that velocity. Exact in the event simulator (its own top-plate kinematics,
  :func:`creeping_plate`), not a staircase. As with ``plate_step`` the images draw the upper plate with the
  structure (DIC never tracks it).
- ``position_force``: an attraction towards the lower plate that depends on where the ball is, not on how
  it moves (a magnet under the plate, electrostatics): F = -weight_fraction m g exp(-d / decay_mm), d the
  gap between the ball and the lower plate (0 in contact); downward on rising and falling flights alike.
  No catalogue term has this shape: Coulomb friction flips sign with the direction of motion, a tilt is
  the same everywhere, drags follow the speed. Combined with a catalogue force the two add.
- ``cor_parity``: the lower plate's COR alternates between ``cor_even`` and ``cor_odd`` on successive
  lower-plate impacts (a period-2 contact state: a ball that lands alternately on two spots of a worn plate):
  impact i (counting every impact from the lead-in's first) gets ``cor_even`` when floor(i / 2) is even, which
  in the rig's two-impacts-per-cycle regime alternates on the lower plate's successive impacts; the upper
  plate keeps the law's COR (the baseline's, or ``asymmetric_restitution``'s ``cor_top``). No catalogue COR
  law has this shape: each gives every impact of a plate at one speed the same COR.

Parameters: {effect: {parameter: (default, min, max)}}, SI except the explicit ``_um``.

Not ball physics at all, so neither in the catalogue nor among the invented effects above (no ``unexplained``
finding is expected of it): :data:`DRIVE_EFFECTS`,

- ``drive_change``: the shaker does not hold its drive (closed-loop control over a long take): the amplitude
  steps smoothly by ``amplitude_step_ratio`` (x the amplitude at t = 0) at ``amplitude_step_time_s`` (camera
  time; logistic, 2 % to 98 % of the step within ``amplitude_ramp_s``) and the frequency drifts linearly by
  ``frequency_drift_hz_per_s`` from the nominal at t = 0, the phase the integral of the frequency
  (:class:`vibro_model.kinematics.DriveChange`; both plates, the lead-in included). The identification must
  report the drive as not stationary (results.json ``drive``) and the discrepancy analysis must not take it
  for a structure tone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from vibro_model.constants import G_MPS2
from vibro_model.kinematics import DriveChange, StructureKinematics, StructureWithTone

from ..forces import ForceLaw, PositionForce
from ..plates import MovedPlate
from ..restitution import RestitutionLaw

INVENTED_EFFECTS: dict[str, dict[str, tuple[float, float, float]]] = {
    "cor_drift": {"drift_per_s": (-0.2, -2.0, 2.0)},
    "structure_tone": {"tone_amplitude_um": (15.0, 0.0, 500.0), "tone_frequency_hz": (7.3, 0.5, 200.0),
                       "tone_phase_rad": (0.4, -2 * math.pi, 2 * math.pi)},
    "plate_step": {"step_um": (60.0, 0.0, 1000.0), "step_time_s": (0.15, 0.0, 100.0)},
    "plate_creep": {"creep_um_per_s": (40.0, -500.0, 500.0)},
    "position_force": {"weight_fraction": (0.25, 0.0, 2.0), "decay_mm": (3.0, 0.05, 100.0)},
    "cor_parity": {"cor_even": (0.62, 0.0, 1.0), "cor_odd": (0.74, 0.0, 1.0)},
}

INVENTED_HELP = {
    "cor_drift": "the COR drifts linearly in time by drift_per_s per second (wear/heating)",
    "structure_tone": "a second structure tone of tone_amplitude_um at tone_frequency_hz, not a drive harmonic",
    "plate_step": "at step_time_s the upper plate backs off upwards by step_um (a loosening screw)",
    "plate_creep": ("the upper plate creeps up by creep_um_per_s every second (negative: down), at the rig's "
                    "height at camera time 0"),
    "position_force": ("a force towards the lower plate, weight_fraction of the ball's weight there, decaying "
                       "over decay_mm with the ball's distance from it, whatever the direction of motion"),
    "cor_parity": "the lower plate's COR alternates between cor_even and cor_odd on successive lower-plate impacts",
}

#: effects of the drive, not of the ball (module docstring): no finding expected, the identification's ``drive``
DRIVE_EFFECTS: dict[str, dict[str, tuple[float, float, float]]] = {
    "drive_change": {"amplitude_step_ratio": (0.1, -0.5, 0.5), "amplitude_step_time_s": (0.75, -100.0, 100.0),
                     "amplitude_ramp_s": (0.1, 0.001, 100.0), "frequency_drift_hz_per_s": (0.0, -1.0, 1.0)},
}

DRIVE_HELP = {
    "drive_change": ("the shaker's amplitude steps by amplitude_step_ratio at amplitude_step_time_s (within "
                     "amplitude_ramp_s) and its frequency drifts by frequency_drift_hz_per_s (Hz/s): not ball "
                     "physics, the identification reports the drive as not stationary"),
}

#: the tone must stay this far (Hz) from every drive harmonic 1..MAX_HARMONIC, else it is a harmonic
TONE_CLEARANCE_HZ = 1.0
MAX_HARMONIC = 5


def check_invented(effects: dict[str, dict[str, float]], frequency_hz: float) -> str | None:
    """Why a set of invented-effect parameters cannot be simulated, or None."""
    tone = effects.get("structure_tone")
    if tone is not None and "drive_change" in effects:
        return "effects 'structure_tone' and 'drive_change' cannot be combined (one structure model holds one of them)"
    if tone is not None:
        f = tone["tone_frequency_hz"]
        for k in range(1, MAX_HARMONIC + 1):
            if abs(f - k * frequency_hz) < TONE_CLEARANCE_HZ:
                return (f"parameter 'tone_frequency_hz' of effect 'structure_tone' ({f} Hz) is within "
                        f"{TONE_CLEARANCE_HZ} Hz of drive harmonic {k} ({k * frequency_hz} Hz): that is "
                        f"structure_harmonics, not an out-of-catalogue tone")
    return None


@dataclass(frozen=True)
class DriftingCOR(RestitutionLaw):
    """e_i = base(plate, v, i) + drift_per_impact * (i - first_index), clipped to [0, 1]."""

    base: RestitutionLaw
    drift_per_impact: float
    first_index: int

    @property
    def effect(self) -> str:  # type: ignore[override]
        return "cor_drift"

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        e = self.base.cor(plate, v_rel_mps, impact_index) + self.drift_per_impact * (impact_index - self.first_index)
        return float(min(1.0, max(0.0, e)))


@dataclass(frozen=True)
class ParityCOR(RestitutionLaw):
    """``cor_parity`` (module docstring): the lower plate's COR ``cor_even`` when floor(i / 2) is even, else
    ``cor_odd``; the upper plate's from ``base``."""

    base: RestitutionLaw
    cor_even: float
    cor_odd: float

    @property
    def effect(self) -> str:  # type: ignore[override]
        return "cor_parity"

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        if plate != "bottom":
            return self.base.cor(plate, v_rel_mps, impact_index)
        return self.cor_even if (int(impact_index) // 2) % 2 == 0 else self.cor_odd

    def parameters(self) -> dict:
        return dict(self.base.parameters(), cor_even=self.cor_even, cor_odd=self.cor_odd)


@dataclass(frozen=True)
class IndexShifted(RestitutionLaw):
    """A law seen from a simulation restarted after ``shift`` impacts: impact i is impact i + shift."""

    base: RestitutionLaw
    shift: int

    @property
    def effect(self) -> str:  # type: ignore[override]
        return getattr(self.base, "effect", "none")

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        return self.base.cor(plate, v_rel_mps, impact_index + self.shift)


def drift_per_impact(drift_per_s: float, frequency_hz: float) -> float:
    """``cor_drift``'s COR change per impact at the rig's two impacts per cycle."""
    return drift_per_s / (2.0 * frequency_hz)


def tone_structure(S: StructureKinematics, tone: dict[str, float]) -> StructureWithTone:
    """``S`` plus the ``structure_tone`` effect's tone."""
    return StructureWithTone(**S.to_dict(), tone_amplitude_m=tone["tone_amplitude_um"] * 1e-6,
                             tone_frequency_hz=tone["tone_frequency_hz"], tone_phase_rad=tone["tone_phase_rad"])


def stepped_cavity(S: StructureKinematics, cavity, step: dict[str, float]):
    """(structure, cavity) after a ``plate_step``: the cavity's free play grows by step/2 and its centre
    moves up by step/2, so the upper plate is ``step_um`` higher and the lower plate stays."""
    half = 0.5e-6 * step["step_um"]
    return replace(S, offset_m=S.offset_m + half), replace(cavity, free_play_m=cavity.free_play_m + half)


def creeping_plate(S: StructureKinematics, creep: dict[str, float]) -> MovedPlate:
    """The upper plate of a ``plate_creep`` on structure ``S``: its motion plus creep_um_per_s * t (t camera time)."""
    return MovedPlate(S, (1e-6 * creep["creep_um_per_s"], 0.0))


def check_creep(effects: dict[str, dict[str, float]], free_play_m: float, horizon_s: float) -> str | None:
    """Why ``plate_creep`` cannot be simulated: a plate that would close the cavity to less than half its free
    play within |t| <= ``horizon_s`` (s) of camera time 0; else None."""
    creep = effects.get("plate_creep")
    if creep is None:
        return None
    travel_m = 1e-6 * abs(creep["creep_um_per_s"]) * horizon_s
    if travel_m >= 0.5 * free_play_m:
        return (f"parameter 'creep_um_per_s' of effect 'plate_creep' ({creep['creep_um_per_s']} um/s) moves the "
                f"upper plate {travel_m * 1e6:.0f} um within the simulated {horizon_s:.3g} s: more than half the "
                f"free play ({free_play_m * 1e6:.0f} um)")
    return None


def position_force(structure: StructureKinematics, cavity, base: ForceLaw, params: dict[str, float]) -> PositionForce:
    """``position_force`` in the cavity ``cavity`` (its free play, ball mass) around the structure motion,
    added to the catalogue force ``base``; the weight is m g with the standard g."""
    return PositionForce(structure, cavity.free_play_m, cavity.mass_kg, G_MPS2, params["weight_fraction"],
                         params["decay_mm"], base)


def drive_structure(S: StructureKinematics, drive: dict[str, float], horizon_s: float) -> DriveChange:
    """``S`` with the ``drive_change`` effect's drive (amplitude step and frequency drift), its derivative bounds
    valid for |t| <= ``horizon_s``. ValueError when the drifting frequency reaches 0 Hz within it."""
    return DriveChange(**S.to_dict(), step_ratio=drive["amplitude_step_ratio"],
                       step_time_s=drive["amplitude_step_time_s"], ramp_s=drive["amplitude_ramp_s"],
                       drift_hz_per_s=drive["frequency_drift_hz_per_s"], horizon_s=horizon_s)


def check_drive(effects: dict[str, dict[str, float]], frequency_hz: float, horizon_s: float) -> str | None:
    """Why the ``drive_change`` parameters cannot be simulated over |t| <= ``horizon_s``, or None."""
    drive = effects.get("drive_change")
    if drive is None:
        return None
    k = drive["frequency_drift_hz_per_s"]
    if frequency_hz - abs(k) * horizon_s <= 0:
        return (f"parameter 'frequency_drift_hz_per_s' of effect 'drive_change' ({k} Hz/s) takes the "
                f"{frequency_hz} Hz drive to 0 Hz within the simulated {horizon_s:.3g} s")
    return None
