"""What the synthetic rig simulates: :class:`SynthConfig`, effects, and the models they give.

Effects use the contract's names and parameter names (docs/recording-format.md);
every parameter name belongs to exactly one effect, so ``--param key=value`` finds its
effect by the key. Extra (non-contract) knobs: ``cor_sigma`` (per-impact Gaussian COR
scatter of ``asymmetric_restitution``, default 0.04 as in the paper's Table 2) and
``h2_phase_rad``/``h3_phase_rad`` of ``structure_harmonics``. Invented effects outside the
discrepancy catalogue (``cor_drift``, ``structure_tone``, ``plate_step``, ``plate_creep``, ``position_force``,
``cor_parity``): :mod:`.invented`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Mapping

from vibro_model.errors import RecordingError
from vibro_model.kinematics import StructureKinematics
from vibro_model.units import m_to_mm, mm_to_m

from ..forces import Coulomb, ForceLaw, NoForce, Quadratic, Viscous
from ..params import BALL_DIAMETER_M, BALL_E_PA, BALL_MASS_KG, BALL_NU, GAP_M, PLATE_E_PA, PLATE_NU, BallCavity
from ..restitution import Constant, PerPlate, RestitutionLaw, Scattered, VelocityDependent
from .invented import (
    DRIVE_EFFECTS,
    INVENTED_EFFECTS,
    DriftingCOR,
    ParityCOR,
    check_creep,
    check_drive,
    check_invented,
    drift_per_impact,
    drive_structure,
    position_force,
    tone_structure,
)
from .spin import SpinCoupled, spin_sequence

if TYPE_CHECKING:
    import numpy as np


class SynthError(RecordingError):
    """Bad synthetic-rig configuration (unknown effect, bad parameter, ...)."""


BASELINE_COR = 0.7
STRUCTURE_MASS_KG = 0.663

# effect -> {parameter: (default, min, max)}; bounds inclusive.
EFFECTS: dict[str, dict[str, tuple[float, float, float]]] = {
    "coulomb_friction": {"force_n": (2.0e-4, 0.0, 1.0e-2)},
    "viscous_drag": {"coefficient_ns_per_m": (2.0e-4, 0.0, 1.0e-1)},
    "quadratic_drag": {"coefficient_ns2_per_m2": (2.0e-4, 0.0, 1.0e-1)},
    "asymmetric_restitution": {"cor_top": (0.6, 0.0, 1.0), "cor_bottom": (0.75, 0.0, 1.0),
                               "cor_sigma": (0.04, 0.0, 0.3)},
    "velocity_dependent_restitution": {"cor_at_zero": (0.85, 0.0, 1.0), "slope_s_per_m": (0.15, -1.0, 5.0)},
    # the axis' TRUE tilt from vertical, concealed (not in rig.yaml); with a declared setup.axis_tilt_deg
    # (SynthConfig.axis_tilt_deg) it is the total tilt, e.g. 50 on a rig declared at 45
    "gravity_tilt": {"tilt_deg": (30.0, -89.0, 179.0)},
    "structure_harmonics": {"h2_ratio": (0.05, 0.0, 0.5), "h3_ratio": (0.02, 0.0, 0.5),
                            "h2_phase_rad": (0.5, -2 * math.pi, 2 * math.pi),
                            "h3_phase_rad": (-0.8, -2 * math.pi, 2 * math.pi)},
}
# every effect the rig simulates: the catalogue's (contract names) and the invented ones outside it
_ALL_EFFECTS = {**EFFECTS, **INVENTED_EFFECTS, **DRIVE_EFFECTS}
EFFECT_NAMES = tuple(EFFECTS) + tuple(INVENTED_EFFECTS) + tuple(DRIVE_EFFECTS) + ("none",)
_PARAM_OWNER = {p: eff for eff, ps in _ALL_EFFECTS.items() for p in ps}
_RESTITUTION = ("asymmetric_restitution", "velocity_dependent_restitution")
_FORCES = ("coulomb_friction", "viscous_drag", "quadratic_drag")

# Default shaker acceleration amplitude (m/s^2) at 22 Hz: chosen by simulation
# (bench/bench_sim.py --regime; tests/test_sim_synth.py checks the baseline) so that the
# baseline and every single effect keep one top and one bottom impact per cycle. The
# scan (4 seeds each) holds from 24 to 36 m/s^2; 20 loses it with Coulomb friction and
# 40 with the harmonics. At 27 the impact phases also repeat cycle to cycle (period 1,
# spread < 0.05 rad without COR scatter). A = 27 / (2 pi 22)^2 = 1.41 mm.
DEFAULT_ACCEL_MPS2 = 27.0
#: The same for a rig mounted (nearly) horizontal (axis tilt >= ``HORIZONTAL_FROM_DEG``): no gravity brings the
#: ball back, the drive alone keeps it crossing the cavity once per half period (a period-1 orbit, one impact
#: on each plate per cycle). At 27 m/s^2 a Coulomb friction of 2e-4 N (the guide rods) loses that orbit for
#: some drive phases; 40 kept it for 12 phases x Coulomb 0, 2e-4 and 1e-4 N at 80-90 deg (scan of
#: :func:`vibro_sim.synth.trajectory.simulate_window`; 5e-4 N loses it for a few phases)
HORIZONTAL_ACCEL_MPS2 = 40.0
#: from this axis tilt (deg) on, gravity along the axis (< 0.2 g) cannot bring the ball to a plate within the
#: lead-in: the ball starts at the speed that crosses the cavity in half a drive period (4 b f)
HORIZONTAL_FROM_DEG = 78.0


@dataclass
class SynthConfig:
    """Everything the synthetic rig needs. Defaults: the paper's Test 1 rig.

    effects        {effect name: {parameter: value}} (contract names; missing
                   parameters take the defaults of ``EFFECTS``); empty = baseline
                   (constant COR 0.7, gravity only, pure sine, vertical).
    frequency_hz   shaker frequency (22 Hz).
    cor            the baseline's constant COR, every plate (0.7); a restitution effect replaces it. A low COR
                   with a drive near g (e.g. cor 0.5, accel_mps2 13 at 10 Hz) gives chatter with sticking:
                   each cycle a flight, hops decaying on the lower plate, then the ball rides the plate
                   until its downward acceleration exceeds g (truth ``contacts``).
    accel_mps2     shaker acceleration amplitude A w^2 (27 m/s^2: two impacts/cycle; ``vibro synth`` takes
                   HORIZONTAL_ACCEL_MPS2 for a rig mounted horizontal).
    axis_tilt_deg  the rig's motion axis from vertical as mounted, declared in rig.yaml ``setup.axis_tilt_deg``
                   (0..90: 0 vertical, 90 horizontal): gravity along the axis g cos(axis_tilt_deg). The concealed
                   ``gravity_tilt`` effect, when chosen, is the axis' true tilt instead (total, from vertical).
    phase_rad      structure phase at camera time 0; None = drawn from the seed.
    seed           seeds every random draw (phase, speckle, noise, COR scatter).
    frames         number of frames (1500 = 1.5 s at 1000 fps).
    fps            camera frame rate (1000).
    lead_in_s      simulated time before frame 0 so that the transient has settled.
    noise_gray     Gaussian read noise sigma in gray levels (of 255) (2).
    flicker        relative amplitude of the illumination flicker (0.01).
    blur           motion blur over ``exposure_s`` centred on each frame time.
    exposure_s     exposure time used for blur (0.5 ms).
    clock_offset_s accelerometer clock minus camera clock (s), at camera time 0.
    daq_clock_ppm  the accelerometer DAQ's clock runs fast by this much against the camera's (ppm; a crystal's
                   error): accel.csv time = camera time + clock_offset_s + daq_clock_ppm 1e-6 camera time.
    still          no motion at all (noise study); ``drift`` adds slow camera drift.
    drift_px       peak camera drift in pixels (vertical) when ``drift``.
    tiff16         write 16-bit TIFF instead of 8-bit PNG.
    bits12         write 16-bit TIFF holding a 12-bit camera's codes (x 4095 / 255, at the top of the word).
    width_px, height_px  image size (160 x 480).
    mm_per_px      image scale; None = 0.06 or larger if the motion needs it.
    accel          write accel.csv (50 kHz) and the rig's accelerometers block.
    accel_rate_hz  accelerometer sample rate (50 kHz).
    accel_noise_mps2  accelerometer noise sigma (m/s^2).
    cor_scatter    per-impact COR scatter of every scenario (dimensionless): impact i's COR
                   is the law's value + cor_scatter z_i, z_i ~ N(0, 1) from the seed, clipped
                   to [0, 1] (0 = none; the paper's Fig. 14-16 show 0.01-0.02). With
                   ``asymmetric_restitution``'s own ``cor_sigma`` the two add in quadrature.
    spin_rad_s, spin_sigma_rad_s
                   the ball's in-plane spin (rad/s, + counter-clockwise on screen): each flight spins at
                   spin_rad_s + spin_sigma_rad_s z, z ~ N(0, 1) drawn anew at every impact (default 0: the
                   ball's texture does not rotate and the frames are those of a build without spin).
    ball_surface   "speckle" (default: a speckle pattern DIC can track) or "shiny": a dark glossy sphere without
                   texture whose specular highlight is fixed relative to the light (real footage's common
                   case; :mod:`.render`).
                   "plain": a uniformly dark ball without texture in front of a bright backlight, a sharp
                   anti-aliased outline (how drop and bounce tests are filmed); rig.yaml then tracks it by its
                   outline (``dic.ball_method: outline``, ``dic.ball_roi`` a box around the whole ball).
    light_deg      with "shiny": the light's angle from the camera axis, tilted towards the image top (30);
                   the highlight sits R sin(light_deg / 2) above the ball's centre.
    jpeg_quality   1..100: every 8-bit frame goes through a JPEG encode/decode at that quality before it is
                   written (lossy video); 0 (default) = none.
    spin_cor_coupling_s_per_rad
                   COR change per rad/s of spin change at the impact (0: the COR ignores the spin); see
                   :mod:`.spin`. DIC follows a rotation of up to a few 0.01 rad from frame 0 (its
                   subsets are translation-only): keep the angle there.
    lens_k1, lens_k2
                   radial distortion (plumb_bob k1, k2) of the lens the frames are seen through (:mod:`.lens`: fx =
                   fy = 1000 px, principal point at the image centre; k1 -0.18 gives a barrel lens whose scale at
                   the lower plate's ROI is ~1.5 % below the centre's). Default 0: no lens, the frames as before.
    lens_calibration_file
                   with a lens: write its calibration (camera_info.yaml) and name it in rig.yaml
                   (``camera.calibration``); False: the recording of a lab that forgot to calibrate.
    """

    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    frequency_hz: float = 22.0
    cor: float = BASELINE_COR
    accel_mps2: float = DEFAULT_ACCEL_MPS2
    axis_tilt_deg: float = 0.0
    phase_rad: float | None = None
    seed: int = 0
    frames: int = 1500
    fps: float = 1000.0
    lead_in_s: float = 1.0
    noise_gray: float = 2.0
    flicker: float = 0.01
    blur: bool = False
    exposure_s: float = 0.5e-3
    clock_offset_s: float = 0.0
    daq_clock_ppm: float = 0.0
    still: bool = False
    drift: bool = False
    drift_px: float = 0.3
    tiff16: bool = False
    bits12: bool = False
    width_px: int = 160
    height_px: int = 480
    mm_per_px: float | None = None
    accel: bool = True
    accel_rate_hz: float = 50_000.0
    accel_noise_mps2: float = 0.5
    cor_scatter: float = 0.0
    spin_rad_s: float = 0.0
    spin_sigma_rad_s: float = 0.0
    spin_cor_coupling_s_per_rad: float = 0.0
    ball_surface: str = "speckle"
    light_deg: float = 30.0
    jpeg_quality: int = 0
    lens_k1: float = 0.0
    lens_k2: float = 0.0
    lens_calibration_file: bool = True
    ball_mass_kg: float = BALL_MASS_KG
    ball_diameter_mm: float = m_to_mm(BALL_DIAMETER_M)
    gap_mm: float = m_to_mm(GAP_M)

    def __post_init__(self) -> None:
        self.effects = normalise_effects(self.effects)
        checks = [
            ("frequency_hz", self.frequency_hz > 0, "> 0"),
            ("cor", 0.0 <= self.cor <= 1.0, "in [0, 1]"), ("accel_mps2", self.accel_mps2 >= 0, ">= 0"),
            ("axis_tilt_deg", 0.0 <= self.axis_tilt_deg <= 90.0,
             "in [0, 90] degrees from vertical (0 vertical, 90 horizontal)"),
            ("frames", isinstance(self.frames, int) and self.frames >= 2, "an integer >= 2"),
            ("fps", self.fps > 0, "> 0"), ("lead_in_s", self.lead_in_s >= 0, ">= 0"),
            ("noise_gray", self.noise_gray >= 0, ">= 0"), ("flicker", 0 <= self.flicker < 0.5, "in [0, 0.5)"),
            ("exposure_s", 0 < self.exposure_s <= 1.0 / self.fps, f"in (0, 1/fps = {1 / self.fps} s]"),
            ("drift_px", abs(self.drift_px) <= 20, "within +-20 px"),
            ("width_px", isinstance(self.width_px, int) and self.width_px >= 64, "an integer >= 64"),
            ("height_px", isinstance(self.height_px, int) and self.height_px >= 128, "an integer >= 128"),
            ("accel_rate_hz", self.accel_rate_hz > 0, "> 0"), ("accel_noise_mps2", self.accel_noise_mps2 >= 0, ">= 0"),
            ("gap_mm", self.gap_mm > self.ball_diameter_mm, "larger than ball_diameter_mm"),
            ("cor_scatter", 0.0 <= self.cor_scatter <= 0.3, "in [0, 0.3]"),
            ("spin_rad_s", abs(self.spin_rad_s) <= 100.0, "within +-100 rad/s"),
            ("spin_sigma_rad_s", 0.0 <= self.spin_sigma_rad_s <= 100.0, "in [0, 100] rad/s"),
            ("spin_cor_coupling_s_per_rad", abs(self.spin_cor_coupling_s_per_rad) <= 1.0, "within +-1 s/rad"),
            ("ball_surface", self.ball_surface in ("speckle", "shiny", "plain"), "'speckle', 'shiny' or 'plain'"),
            ("light_deg", 0.0 <= self.light_deg < 180.0, "in [0, 180) degrees"),
            ("jpeg_quality", isinstance(self.jpeg_quality, int) and 0 <= self.jpeg_quality <= 100,
             "an integer in [0, 100] (0 = no JPEG)"),
            ("lens_k1", abs(self.lens_k1) <= 2.0, "within +-2"), ("lens_k2", abs(self.lens_k2) <= 2.0, "within +-2"),
        ]
        for name, ok, expect in checks:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                ok = False
            if not ok:
                raise SynthError(f"synth option '{name}' must be {expect}, got {value!r}")
        if self.mm_per_px is not None and not self.mm_per_px > 0:
            raise SynthError(f"synth option 'mm_per_px' must be > 0, got {self.mm_per_px!r}")
        if self.jpeg_quality and (self.tiff16 or self.bits12):
            raise SynthError("synth option 'jpeg_quality' needs 8-bit frames (not tiff16)")
        if not math.isfinite(self.clock_offset_s) or abs(self.clock_offset_s) > 1.0:
            raise SynthError(f"synth option 'clock_offset_s' must be within +-1 s, got {self.clock_offset_s!r}")
        if not math.isfinite(self.daq_clock_ppm) or abs(self.daq_clock_ppm) > 10_000.0:
            raise SynthError(f"synth option 'daq_clock_ppm' must be within +-10000 ppm, got {self.daq_clock_ppm!r}")
        why = check_invented(self.effects, self.frequency_hz)
        if why is not None:
            raise SynthError(why)
        why = check_drive(self.effects, self.frequency_hz, drive_horizon_s(self))
        if why is not None:
            raise SynthError(why)
        why = check_creep(self.effects, 0.5 * mm_to_m(self.gap_mm - self.ball_diameter_mm), drive_horizon_s(self))
        if why is not None:
            raise SynthError(why)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def normalise_effects(effects: Mapping[str, Mapping[str, Any]] | None) -> dict[str, dict[str, float]]:
    """Validate effect names and parameters; fill defaults. Raises :class:`SynthError`."""
    out: dict[str, dict[str, float]] = {}
    for name, params in (effects or {}).items():
        if name == "none":
            continue
        if name not in _ALL_EFFECTS:
            raise SynthError(f"unknown effect '{name}' (choose from: {', '.join(EFFECT_NAMES)})")
        spec = _ALL_EFFECTS[name]
        values = {k: d for k, (d, _, _) in spec.items()}
        for key, value in (params or {}).items():
            if key not in spec:
                raise SynthError(f"effect '{name}' has no parameter '{key}' (it takes: {', '.join(spec)})")
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise SynthError(f"parameter '{key}' of effect '{name}' must be a number, got {value!r}") from None
            _, lo, hi = spec[key]
            if not math.isfinite(value) or not lo <= value <= hi:
                raise SynthError(f"parameter '{key}' of effect '{name}' must be in [{lo}, {hi}], got {value!r}")
            values[key] = value
        out[name] = values
    if sum(n in out for n in _RESTITUTION) > 1:
        raise SynthError(f"choose at most one restitution effect ({' or '.join(_RESTITUTION)})")
    if sum(n in out for n in _FORCES) > 1:
        raise SynthError(f"choose at most one flight-force effect ({', '.join(_FORCES)})")
    return out


def parse_effect_args(effect_names: list[str] | None, params: list[str] | None) -> dict[str, dict[str, float]]:
    """CLI form: ``--effect NAME`` (repeatable) and ``--param key=value`` (repeatable).

    Each parameter goes to the chosen effect that owns its key (keys are unique across
    effects). Raises :class:`SynthError` with a clear message.
    """
    chosen: dict[str, dict[str, Any]] = {}
    for name in effect_names or []:
        if name not in EFFECT_NAMES:
            raise SynthError(f"--effect: unknown effect '{name}' (choose from: {', '.join(EFFECT_NAMES)})")
        if name != "none":
            chosen.setdefault(name, {})
    for item in params or []:
        if "=" not in item:
            raise SynthError(f"--param '{item}': expected key=value, e.g. force_n=2e-4")
        key, value = (s.strip() for s in item.split("=", 1))
        owner = _PARAM_OWNER.get(key)
        if owner is None:
            raise SynthError(f"--param '{item}': unknown parameter '{key}' (known: {', '.join(_PARAM_OWNER)})")
        if owner not in chosen:
            raise SynthError(f"--param '{item}': '{key}' belongs to effect '{owner}', which was not "
                             f"chosen (add --effect {owner})")
        try:
            chosen[owner][key] = float(value)
        except ValueError:
            raise SynthError(f"--param '{item}': value '{value}' is not a number") from None
    return normalise_effects(chosen)


@dataclass(kw_only=True)
class Models:
    """The physics of one scenario."""

    structure: StructureKinematics
    cavity: BallCavity
    restitution: RestitutionLaw
    force: ForceLaw
    law_without_scatter: RestitutionLaw | None = None   # the COR law before the per-impact scatter
    plate_step: dict[str, float] | None = None          # the invented plate_step effect's parameters
    plate_creep: dict[str, float] | None = None         # the invented plate_creep effect's parameters
    cor_drift_per_impact: float = 0.0                   # the invented cor_drift (from frame 0 on)
    law_before_scatter: RestitutionLaw | None = None    # the law before cor_scatter (with asymmetric's own)
    cor_scatter: float = 0.0
    scatter_seed: int = 0
    spins_rad_s: "np.ndarray | None" = None             # the ball's spin per flight (synth.spin); None: no spin

    @property
    def spinning(self) -> bool:
        return self.spins_rad_s is not None

    def window_laws(self, first_index: int) -> tuple[RestitutionLaw, RestitutionLaw | None]:
        """(COR law, the same without scatter) from the camera window's first impact ``first_index`` on:
        the lead-in's laws unless ``cor_drift`` starts drifting there."""
        if not self.cor_drift_per_impact:
            return self.restitution, self.law_without_scatter
        law: RestitutionLaw = DriftingCOR(self.law_before_scatter, self.cor_drift_per_impact, first_index)
        if self.cor_scatter > 0:
            law = Scattered(law, self.cor_scatter, seed=self.scatter_seed)
        return law, DriftingCOR(self.law_without_scatter, self.cor_drift_per_impact, first_index)


def build_models(cfg: SynthConfig, phase_rad: float) -> Models:
    """Structure, cavity and laws for ``cfg`` (SI; structure offset 0 = lab origin)."""
    eff = cfg.effects
    w = 2 * math.pi * cfg.frequency_hz
    h = eff.get("structure_harmonics", {})
    amp = 0.0 if cfg.still else cfg.accel_mps2 / w ** 2
    structure = StructureKinematics(amplitude_m=amp, frequency_hz=cfg.frequency_hz, phase_rad=phase_rad,
                                    offset_m=0.0, h2_ratio=h.get("h2_ratio", 0.0), h3_ratio=h.get("h3_ratio", 0.0),
                                    h2_phase_rad=h.get("h2_phase_rad", 0.0),
                                    h3_phase_rad=h.get("h3_phase_rad", 0.0))
    cavity = BallCavity(mass_kg=cfg.ball_mass_kg, radius_m=0.5 * mm_to_m(cfg.ball_diameter_mm),
                        free_play_m=0.5 * mm_to_m(cfg.gap_mm - cfg.ball_diameter_mm),
                        tilt_deg=eff.get("gravity_tilt", {}).get("tilt_deg", cfg.axis_tilt_deg),
                        ball_E_pa=BALL_E_PA, ball_nu=BALL_NU, plate_E_pa=PLATE_E_PA, plate_nu=PLATE_NU)
    if "structure_tone" in eff:
        structure = tone_structure(structure, eff["structure_tone"])
    if "drive_change" in eff:
        structure = drive_structure(structure, eff["drive_change"], drive_horizon_s(cfg))
    law, force = effect_laws(eff, scatter_seed=cfg.seed + 7919, baseline_cor=cfg.cor)
    if "position_force" in eff:
        force = position_force(structure, cavity, force, eff["position_force"])
    plain_law = effect_laws(eff, baseline_cor=cfg.cor)[0]   # the law without per-impact scatter (truth: cor_law)
    spins = None
    if cfg.spin_rad_s != 0.0 or cfg.spin_sigma_rad_s > 0.0:
        spins = spin_sequence(cfg.spin_rad_s, cfg.spin_sigma_rad_s, cfg.seed)
        if cfg.spin_cor_coupling_s_per_rad != 0.0:
            law = SpinCoupled(law, spins, cfg.spin_cor_coupling_s_per_rad)
    before_scatter = law
    if cfg.cor_scatter > 0:
        law = Scattered(law, cfg.cor_scatter, seed=cfg.seed + 104729)
    drift = drift_per_impact(eff["cor_drift"]["drift_per_s"], cfg.frequency_hz) if "cor_drift" in eff else 0.0
    return Models(structure=structure, cavity=cavity, restitution=law, force=force, law_without_scatter=plain_law,
                  plate_step=eff.get("plate_step"), plate_creep=eff.get("plate_creep"), cor_drift_per_impact=drift,
                  law_before_scatter=before_scatter,
                  cor_scatter=cfg.cor_scatter, scatter_seed=cfg.seed + 104729, spins_rad_s=spins)


def effect_laws(effects: Mapping[str, Mapping[str, float]], scatter_seed: int | None = None,
                baseline_cor: float = BASELINE_COR) -> tuple[RestitutionLaw, ForceLaw]:
    """The COR law and flight force law of a set of contract effects ({name: parameters}, SI).

    The baseline is a constant COR (``baseline_cor``) and no force. ``scatter_seed`` draws the asymmetric case's
    per-impact COR scatter (``cor_sigma``); None leaves the scatter out (the deterministic law).
    """
    law: RestitutionLaw = Constant(baseline_cor)
    if "asymmetric_restitution" in effects:
        p = effects["asymmetric_restitution"]
        law = PerPlate(p["cor_top"], p["cor_bottom"])
        if scatter_seed is not None and p.get("cor_sigma", 0.0) > 0:
            law = Scattered(law, p["cor_sigma"], seed=scatter_seed)
    elif "velocity_dependent_restitution" in effects:
        p = effects["velocity_dependent_restitution"]
        law = VelocityDependent(p["cor_at_zero"], p["slope_s_per_m"])
    if "cor_parity" in effects:   # out of the catalogue (:mod:`.invented`): the lower plate alternates
        law = ParityCOR(law, effects["cor_parity"]["cor_even"], effects["cor_parity"]["cor_odd"])
    force: ForceLaw = NoForce()
    if "coulomb_friction" in effects:
        force = Coulomb(effects["coulomb_friction"]["force_n"])
    elif "viscous_drag" in effects:
        force = Viscous(effects["viscous_drag"]["coefficient_ns_per_m"])
    elif "quadratic_drag" in effects:
        force = Quadratic(effects["quadratic_drag"]["coefficient_ns2_per_m2"])
    return law, force


def effects_truth(cfg: SynthConfig) -> list[dict[str, Any]]:
    """The truth file's ``effects`` list (contract parameter names; extras kept)."""
    if not cfg.effects:
        return [{"effect": "none", "parameters": {}}]
    out = []
    for name, params in cfg.effects.items():
        row: dict[str, Any] = {"effect": name, "parameters": dict(params)}
        if name in INVENTED_EFFECTS:
            # not a contract effect: the discrepancy analysis has no term for it and must report it unexplained
            row.update(out_of_catalogue=True, expected_finding="unexplained")
        if name in DRIVE_EFFECTS:
            # the drive, not the ball: results.json ``drive`` says it is not stationary; no finding for it
            row.update(out_of_catalogue=True, expected_finding="none", expected_section="drive",
                       convention=("A(t) = amplitude_mm [1 + amplitude_step_ratio (1 + tanh(4 (t - "
                                   "amplitude_step_time_s) / amplitude_ramp_s)) / 2], f(t) = frequency_hz + "
                                   "frequency_drift_hz_per_s t, th = phase_rad + 2 pi int_0^t f; structure.* at t = 0"))
        out.append(row)
    return out


def drive_horizon_s(cfg: SynthConfig) -> float:
    """|t| (s) within which the simulation stays (the lead-in before camera time 0, the frames after it)."""
    return cfg.lead_in_s + cfg.frames / cfg.fps + 1.0
