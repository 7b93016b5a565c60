"""The results document of one recording as types: SI inside (m, m/s, m/s^2, s, N), contract keys outside.

``to_dict()`` gives the results.json keys of docs/recording-format.md (positions in mm, flight
coefficients for Y[mm] = a t^2 + b t + c, velocities in m/s, times in s, forces in N, JSON null for an
unknown number); ``from_dict(data, where)`` reads them back, validating each key (errors name
``where.key``). Unknown numbers are None inside, never NaN. Sections the model does not type yet
(cor_statistics, regime, identification, accelerometers, the discrepancy engine's extras) are kept as
plain JSON in ``sections`` / ``details``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from vibro_model.codec import SCHEMA, Fields, ResultsError, json_number, json_value
from vibro_model.kinematics import StructureKinematics
from vibro_model.units import m_to_mm, mm_to_m

PLATES = ("top", "bottom")
DIRECTIONS = ("up", "down")
MODELS = ("cor_model", "hertz_model")
#: top-level keys every results.json has (docs/recording-format.md)
REQUIRED_KEYS = ("schema", "recording", "structure", "flights", "impacts", "cor_summary", "simulation",
                 "discrepancy")


@dataclass(kw_only=True)
class StructureMotion:
    """Y_s(t) = A sin(2 pi f t + phi) + B, t camera time (s); 1-sigma stds from the fit covariance.

    ``ball_offset_m``: ball centre minus cavity centre at frame 0 (from where the impacts happen)."""

    amplitude_m: float | None         # A (m)
    frequency_hz: float | None        # f (Hz)
    phase_rad: float | None           # phi (rad)
    offset_m: float | None            # B (m), DIC frame: displacement since frame 0
    rms_residual_m: float | None = None
    amplitude_std_m: float | None = None
    frequency_std_hz: float | None = None
    phase_std_rad: float | None = None
    offset_std_m: float | None = None
    n_points: int | None = None       # frames used in the fit
    ball_offset_m: float | None = None
    moving: bool = True               # False: the sine does not stand out of the DIC noise (no f, phi claimed)
    note: str = ""

    def to_dict(self) -> dict:
        out = {"amplitude_mm": m_to_mm(self.amplitude_m), "frequency_hz": self.frequency_hz,
               "phase_rad": self.phase_rad, "offset_mm": m_to_mm(self.offset_m),
               "rms_residual_mm": m_to_mm(self.rms_residual_m), "amplitude_std_mm": m_to_mm(self.amplitude_std_m),
               "frequency_std_hz": self.frequency_std_hz, "phase_std_rad": self.phase_std_rad,
               "offset_std_mm": m_to_mm(self.offset_std_m), "n_points": self.n_points,
               "ball_offset_mm": m_to_mm(self.ball_offset_m)}
        out = {k: json_number(v) for k, v in out.items()}
        out["moving"] = bool(self.moving)
        if self.note:
            out["note"] = self.note
        return out

    def kinematics(self) -> StructureKinematics:
        """The identified sine Y_s(t) = A sin(2 pi f t + phi) + B as the structure motion the simulator and
        the discrepancy analysis use (m, s; DIC frame); ValueError when a parameter is unknown."""
        values = (self.amplitude_m, self.frequency_hz, self.phase_rad, self.offset_m)
        if any(v is None for v in values):
            raise ValueError("the structure sine is not known (amplitude, frequency, phase or offset missing)")
        return StructureKinematics(*values)

    @classmethod
    def from_dict(cls, data: Any, where: str = "structure") -> "StructureMotion":
        f = Fields(data, where)
        return cls(amplitude_m=mm_to_m(f.number("amplitude_mm")), frequency_hz=f.number("frequency_hz"),
                   phase_rad=f.number("phase_rad"),
                   offset_m=mm_to_m(f.number("offset_mm")), rms_residual_m=mm_to_m(f.number("rms_residual_mm")),
                   amplitude_std_m=mm_to_m(f.number("amplitude_std_mm", False)),
                   frequency_std_hz=f.number("frequency_std_hz", False),
                   phase_std_rad=f.number("phase_std_rad", False), offset_std_m=mm_to_m(f.number("offset_std_mm",
                                                                                                 False)),
                   n_points=f.integer("n_points", False, nullable=True),
                   ball_offset_m=mm_to_m(f.number("ball_offset_mm", False)),
                   moving=f.boolean("moving", True), note=f.string("note", False, default=""))


@dataclass(kw_only=True)
class Flight:
    """One fitted flight: Y_b[m] = a t^2 + b t + c, t absolute camera time (s); friction (Eq. 17, N, + up)
    only for a free flight. ``t_start_s``/``t_end_s`` are the impacts that open/close it when known,
    else its first/last fitted frame. ``friction_method`` (None: Eq. 17 as identified) names the discrepancy
    finding the friction was corrected for (``gravity_tilt``: an undeclared tilt's constant force m c along the
    axis subtracted), ``friction_paper_n`` then keeps the identification's Eq. 17 value."""

    index: int
    t_first_frame_s: float | None
    t_last_frame_s: float | None
    a_mps2: float | None
    b_mps: float | None
    c_m: float | None
    direction: str
    friction_n: float | None
    friction_std_n: float | None
    rms_residual_m: float | None
    n_points: int | None
    free: bool
    reason: str = ""
    t_opening_impact_s: float | None = None
    t_closing_impact_s: float | None = None
    friction_method: str | None = None
    friction_paper_n: float | None = None

    @property
    def t_start_s(self) -> float | None:
        return self.t_first_frame_s if self.t_opening_impact_s is None else self.t_opening_impact_s

    @property
    def t_end_s(self) -> float | None:
        return self.t_last_frame_s if self.t_closing_impact_s is None else self.t_closing_impact_s

    def to_dict(self) -> dict:
        out = {"index": self.index, "t_start": self.t_start_s, "t_end": self.t_end_s,
               "t_first_frame": self.t_first_frame_s, "t_last_frame": self.t_last_frame_s,
               "a": m_to_mm(self.a_mps2), "b": m_to_mm(self.b_mps), "c": m_to_mm(self.c_m),
               "direction": self.direction or "up", "friction_n": self.friction_n,
               "friction_std_n": self.friction_std_n, "rms_residual_mm": m_to_mm(self.rms_residual_m),
               "n_points": self.n_points, "free": self.free, "reason": self.reason}
        if self.friction_method is not None:
            out.update({"friction_method": self.friction_method, "friction_paper_n": self.friction_paper_n})
        return {k: json_number(v) if not isinstance(v, str) else v for k, v in out.items()}

    @classmethod
    def from_dict(cls, data: Any, where: str = "flights[]") -> "Flight":
        f = Fields(data, where)
        t_start, t_end = f.number("t_start"), f.number("t_end")
        first = f.number("t_first_frame", False) if "t_first_frame" in f.data else t_start
        last = f.number("t_last_frame", False) if "t_last_frame" in f.data else t_end
        friction = f.number("friction_n")
        return cls(index=f.integer("index"), t_first_frame_s=first, t_last_frame_s=last, a_mps2=mm_to_m(f.number("a")),
                   b_mps=mm_to_m(f.number("b")),
                   c_m=mm_to_m(f.number("c")), direction=f.string("direction", choices=DIRECTIONS), friction_n=friction,
                   friction_std_n=f.number("friction_std_n", False),
                   rms_residual_m=mm_to_m(f.number("rms_residual_mm")),
                   n_points=f.integer("n_points", False, nullable=True), free=f.boolean("free", friction is not None),
                   reason=f.string("reason", False, default=""),
                   friction_method=f.string("friction_method", False),
                   friction_paper_n=f.number("friction_paper_n", False),
                   t_opening_impact_s=t_start if t_start != first else None,
                   t_closing_impact_s=t_end if t_end != last else None)


@dataclass(kw_only=True)
class Impact:
    """One impact (Eq. 15, 16): time (s), plate, COR e = -(v_after - v_s) / (v_before - v_s), velocities
    (m/s, + up) and the indices of the flights that end / start there.

    ``cor_method`` says which model measured ``t``, ``cor``, ``cor_std`` and ``v_*``: ``"paper"`` (the
    identification, Eq. 15-16) or the '+'-joined names of the discrepancy findings whose model re-measured
    them (:mod:`vibro_discrepancy.reidentify`); ``cor_paper``, ``cor_std_paper``, ``t_paper_s`` keep
    the identification's values beside them. All four are None in a document written before they existed
    (or rebuilt from a graph run's messages) and are then not written.

    The one impact type: the identification's estimates (:class:`vibro_fit.impacts.ImpactFit` adds the fit
    context), the simulators' impact events (:mod:`vibro_sim.cor_model`, ``cor_std`` None) and the synthetic
    truth (:mod:`vibro_fit.synthetic`) are all Impacts.

    ``cor_std_model`` is the share of ``cor_std`` that is model error: what the model leaves in its residuals
    near the impact (:mod:`vibro_model.model_error`; cor_std^2 = noise^2 + cor_std_model^2), None (not written)
    where none was found.

    ``in_gap`` is true for an impact found inside a run of lost frames from the flights on both sides
    (:mod:`vibro_fit.gaps`), ``gap_lost_frames`` the frames lost between those flights; its sigmas are
    ``t_std``/``cor_std``. Both None (not written) for an impact the camera saw."""

    index: int
    t_s: float | None
    plate: str
    cor: float | None
    cor_std: float | None
    v_ball_before_mps: float | None
    v_ball_after_mps: float | None
    v_structure_mps: float | None
    t_std_s: float | None = None
    flight_before: int | None = None
    flight_after: int | None = None
    method: str | None = None
    cor_method: str | None = None
    cor_paper: float | None = None
    cor_std_paper: float | None = None
    t_paper_s: float | None = None
    in_gap: bool | None = None
    gap_lost_frames: int | None = None
    cor_std_model: float | None = None   # the share of cor_std that is model error (vibro_model.model_error)

    @property
    def cor_std_noise(self) -> float | None:
        """The noise share of ``cor_std``: its model error (``cor_std_model``) taken out (None when unknown). The
        checks that look for what the model misses (a COR outside [0, 1], the discrepancy analysis' floors) judge
        against it: the model error is made of that miss."""
        if self.cor_std is None:
            return None
        model = self.cor_std_model or 0.0
        return math.sqrt(max(self.cor_std * self.cor_std - model * model, 0.0))

    @property
    def v_rel_before_mps(self) -> float:
        """Ball minus structure velocity just before the impact (m/s; > 0: moving up towards the top plate)."""
        return self.v_ball_before_mps - self.v_structure_mps

    @property
    def v_rel_after_mps(self) -> float:
        """Ball minus structure velocity just after the impact (m/s)."""
        return self.v_ball_after_mps - self.v_structure_mps

    def to_dict(self) -> dict:
        out = {"index": self.index, "t": self.t_s, "t_std": self.t_std_s, "plate": self.plate, "cor": self.cor,
               "cor_std": self.cor_std, "v_ball_before": self.v_ball_before_mps,
               "v_ball_after": self.v_ball_after_mps, "v_structure": self.v_structure_mps,
               "flight_before": self.flight_before, "flight_after": self.flight_after}
        out = {k: json_number(v) if not isinstance(v, str) else v for k, v in out.items()}
        if self.method is not None:
            out["method"] = self.method
        if self.cor_method is not None:
            out.update({"cor_method": self.cor_method, "cor_paper": json_number(self.cor_paper),
                        "cor_std_paper": json_number(self.cor_std_paper), "t_paper": json_number(self.t_paper_s)})
        if self.cor_std_model is not None:
            out["cor_std_model"] = json_number(self.cor_std_model)
        if self.in_gap is not None:
            out["in_gap"] = bool(self.in_gap)
            out["gap_lost_frames"] = None if self.gap_lost_frames is None else int(self.gap_lost_frames)
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "impacts[]") -> "Impact":
        f = Fields(data, where)
        return cls(index=f.integer("index"), t_s=f.number("t"), plate=f.string("plate", choices=PLATES),
                   cor=f.number("cor"),
                   cor_std=f.number("cor_std"), v_ball_before_mps=f.number("v_ball_before"),
                   v_ball_after_mps=f.number("v_ball_after"),
                   v_structure_mps=f.number("v_structure"), t_std_s=f.number("t_std", False),
                   flight_before=f.integer("flight_before", False, True),
                   flight_after=f.integer("flight_after", False, True), method=f.string("method", False),
                   cor_method=f.string("cor_method", False), cor_paper=f.number("cor_paper", False),
                   cor_std_paper=f.number("cor_std_paper", False),
                   t_paper_s=f.number("t_paper", False), in_gap=f.boolean("in_gap", None),  # type: ignore[arg-type]
                   gap_lost_frames=f.integer("gap_lost_frames", False, True),
                   cor_std_model=f.number("cor_std_model", False))


@dataclass
class PlateCor:
    """Sample mean and std (ddof = 1) of one plate's CORs: mean None for n = 0, std None for n < 2."""

    mean: float | None
    std: float | None
    n: int

    @classmethod
    def of(cls, cors: Sequence[float]) -> "PlateCor":
        vals = np.asarray(cors, dtype=float)
        return cls(float(vals.mean()) if vals.size else None, float(vals.std(ddof=1)) if vals.size > 1 else None,
                   int(vals.size))

    def to_dict(self) -> dict:
        return {"mean": json_number(self.mean), "std": json_number(self.std), "n": self.n}

    @classmethod
    def from_dict(cls, data: Any, where: str) -> "PlateCor":
        f = Fields(data, where)
        return cls(f.number("mean"), f.number("std"), f.integer("n"))


@dataclass
class CorSummary:
    """COR per plate (the paper's Table 2)."""

    top: PlateCor
    bottom: PlateCor

    @classmethod
    def of(cls, impacts: Iterable) -> "CorSummary":
        """From anything with ``plate`` and ``cor`` (an unknown COR counts as NaN, as the fit gave it)."""
        impacts = list(impacts)
        cors = {p: [np.nan if i.cor is None else i.cor for i in impacts if i.plate == p] for p in PLATES}
        return cls(PlateCor.of(cors["top"]), PlateCor.of(cors["bottom"]))

    def to_dict(self) -> dict:
        return {"top": self.top.to_dict(), "bottom": self.bottom.to_dict()}

    @classmethod
    def from_dict(cls, data: Any, where: str = "cor_summary") -> "CorSummary":
        f = Fields(data, where)
        return cls(*(PlateCor.from_dict(f.value(p, True), f"{where}.{p}") for p in PLATES))


@dataclass
class SimulationRun:
    """One model replayed over the measured run: D (Eq. 18, a fraction) and, when kept, the simulated and
    measured ball displacement (m, DIC frame) at the sample times (s)."""

    model: str
    deviation: float | None
    n_impacts: int | None = None
    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0), compare=False)
    ball_m: np.ndarray = field(default_factory=lambda: np.zeros(0), compare=False)
    measured_ball_m: np.ndarray = field(default_factory=lambda: np.zeros(0), compare=False)


@dataclass
class Simulation:
    """The ``simulation`` section: D per model (cor_model and hertz_model always present, None when not run)."""

    runs: dict[str, SimulationRun] = field(default_factory=dict)

    @classmethod
    def of_deviations(cls, deviations: Mapping[str, float | None]) -> "Simulation":
        return cls({name: SimulationRun(name, json_number(d)) for name, d in deviations.items()})

    def deviation(self, model: str) -> float | None:
        run = self.runs.get(model)
        return None if run is None else run.deviation

    def to_dict(self) -> dict:
        names = list(MODELS) + [m for m in self.runs if m not in MODELS]
        return {name: {"deviation": json_number(self.deviation(name))} for name in names}

    @classmethod
    def from_dict(cls, data: Any, where: str = "simulation") -> "Simulation":
        f = Fields(data, where)
        runs = {}
        for name in list(MODELS) + [k for k in f.data if k not in MODELS]:
            sub = f.mapping(name)
            runs[name] = SimulationRun(name, sub.number("deviation"))
        return cls(runs)


@dataclass
class DiscrepancyFinding:
    """One piece of physics the baseline model left out: contract effect name, SI parameters (and their
    1-sigma stds), where it shows, D without and with it. ``details``: the engine's extra keys."""

    effect: str
    parameters: dict[str, float | None]
    where: str
    deviation_before: float | None
    deviation_after: float | None
    parameters_std: dict[str, float | None] | None = None
    details: dict[str, Any] = field(default_factory=dict)

    KEYS = ("effect", "parameters", "parameters_std", "where", "deviation_before", "deviation_after")

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"effect": self.effect, "parameters": json_value(self.parameters)}
        if self.parameters_std is not None:
            out["parameters_std"] = json_value(self.parameters_std)
        out.update({"where": self.where, "deviation_before": json_number(self.deviation_before),
                    "deviation_after": json_number(self.deviation_after)})
        out.update(json_value(self.details))
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "findings[]") -> "DiscrepancyFinding":
        f = Fields(data, where)
        return cls(f.string("effect"), f.numbers_by_name("parameters"), f.string("where"),
                   f.number("deviation_before"), f.number("deviation_after"),
                   f.numbers_by_name("parameters_std", False), f.extras(cls.KEYS))


@dataclass
class Discrepancy:
    """The ``discrepancy`` section: D of the baseline, the findings in order, D of the final model;
    ``details``: the engine's extras (model, noise floors, location, stages, notes, error)."""

    baseline_deviation: float | None = None
    findings: list[DiscrepancyFinding] = field(default_factory=list)
    final_deviation: float | None = None
    details: dict[str, Any] = field(default_factory=dict)

    KEYS = ("baseline_deviation", "findings", "final_deviation")

    def to_dict(self) -> dict:
        out = {"baseline_deviation": json_number(self.baseline_deviation),
               "findings": [fd.to_dict() for fd in self.findings],
               "final_deviation": json_number(self.final_deviation)}
        out.update(json_value(self.details))
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "discrepancy") -> "Discrepancy":
        f = Fields(data, where)
        findings = [DiscrepancyFinding.from_dict(r.data, r.where) for r in f.rows("findings")]
        return cls(f.number("baseline_deviation"), findings, f.number("final_deviation"), f.extras(cls.KEYS))


def link_impacts(flights: Iterable[Flight], impacts: Iterable[Impact]) -> list[Flight]:
    """The flights with the times of the impacts that open (``flight_after``) and close (``flight_before``)
    each of them; a flight without such an impact keeps its first/last fitted frame."""
    impacts = list(impacts)
    opens = {i.flight_after: i.t_s for i in impacts if i.flight_after is not None}
    closes = {i.flight_before: i.t_s for i in impacts if i.flight_before is not None}
    return [replace(f, t_opening_impact_s=opens.get(f.index), t_closing_impact_s=closes.get(f.index))
            for f in flights]


@dataclass(kw_only=True)
class ResultsDocument:
    """The whole results.json of one recording (schema vibro.results/1).

    ``complete`` is False for a document rebuilt from a run that did not finish (a bag cut short): its
    flights and impacts are then the streamed estimates, and ``warnings`` says what is missing.
    ``sections``: further top-level sections as plain JSON (cor_statistics, regime, identification,
    accelerometers)."""

    recording: str
    structure: StructureMotion | None
    flights: list[Flight]
    impacts: list[Impact]
    cor_summary: CorSummary
    simulation: Simulation = field(default_factory=Simulation)
    discrepancy: Discrepancy = field(default_factory=Discrepancy)
    warnings: list[str] = field(default_factory=list)
    complete: bool = True
    sections: dict[str, Any] = field(default_factory=dict)

    KEYS = ("schema", "recording", "complete", "structure", "flights", "impacts", "cor_summary", "warnings",
            "simulation", "discrepancy")

    @classmethod
    def build(cls, recording: str, structure: StructureMotion | None, flights: Iterable[Flight],
              impacts: Iterable[Impact], *, simulation: Simulation | None = None,
              discrepancy: Discrepancy | None = None, warnings: Iterable[str] = (),
              sections: Mapping[str, Any] | None = None) -> "ResultsDocument":
        """The document from its parts (marked complete): impacts sorted by index, flights by index and linked to
        their opening/closing impacts (:func:`link_impacts`), the COR summary from the impacts. The results
        assembler (:func:`vibro_model.assemble.assemble_results`) is the one caller that writes results.json."""
        impacts = sorted(impacts, key=lambda i: i.index)
        flights = link_impacts(sorted(flights, key=lambda f: f.index), impacts)
        return cls(recording=str(recording), structure=structure, flights=flights, impacts=impacts,
                   cor_summary=CorSummary.of(impacts),
                   simulation=simulation or Simulation.of_deviations({m: None for m in MODELS}),
                   discrepancy=discrepancy or Discrepancy(), warnings=list(warnings), sections=dict(sections or {}))

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"schema": SCHEMA, "recording": self.recording, "complete": self.complete,
                               "structure": None if self.structure is None else self.structure.to_dict(),
                               "flights": [f.to_dict() for f in self.flights],
                               "impacts": [i.to_dict() for i in self.impacts],
                               "cor_summary": self.cor_summary.to_dict()}
        out.update(json_value(self.sections))
        out["warnings"] = list(self.warnings)
        out["simulation"] = self.simulation.to_dict()
        out["discrepancy"] = self.discrepancy.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: Any, source: str = "results") -> "ResultsDocument":
        f = Fields(data, source)
        missing = [k for k in REQUIRED_KEYS if k not in f.data]
        if missing:
            raise ResultsError(f"{source}: not a vibro results document: missing key(s) {', '.join(missing)}")
        schema = f.string("schema")
        if schema != SCHEMA:
            raise ResultsError(f"{source}.schema: expected {SCHEMA!r}, got {schema!r}")
        complete = f.boolean("complete", True)
        structure = f.value("structure", True)
        if structure is None and complete:
            raise ResultsError(f"{source}.structure: null in a document marked complete")
        warnings = f.value("warnings", False) or []
        if not isinstance(warnings, list) or not all(isinstance(w, str) for w in warnings):
            raise ResultsError(f"{source}.warnings: must be a list of strings")
        return cls(recording=f.string("recording"),
                   structure=None if structure is None else StructureMotion.from_dict(structure,
                                                                                      f"{source}.structure"),
                   flights=[Flight.from_dict(r.data, r.where) for r in f.rows("flights")],
                   impacts=[Impact.from_dict(r.data, r.where) for r in f.rows("impacts")],
                   cor_summary=CorSummary.from_dict(f.value("cor_summary", True), f"{source}.cor_summary"),
                   simulation=Simulation.from_dict(f.value("simulation", True), f"{source}.simulation"),
                   discrepancy=Discrepancy.from_dict(f.value("discrepancy", True), f"{source}.discrepancy"),
                   warnings=list(warnings), complete=complete, sections=f.extras(cls.KEYS))


def as_document(doc: ResultsDocument | Mapping[str, Any], source: str = "results") -> ResultsDocument:
    """A :class:`ResultsDocument`, validating a mapping on the way (errors name ``source`` and the key)."""
    return doc if isinstance(doc, ResultsDocument) else ResultsDocument.from_dict(doc, source)


def results_text(doc: ResultsDocument | Mapping[str, Any]) -> str:
    """The JSON text of a results document (validated; strict JSON: no NaN, indented)."""
    return json.dumps(as_document(doc).to_dict(), indent=2, allow_nan=False) + "\n"
