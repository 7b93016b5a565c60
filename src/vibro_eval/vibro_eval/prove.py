"""``vibro prove``: blind proof of the discrepancy analysis on concealed effects.

Each case draws an effect (or none: a control) with its magnitude, the excitation and the image noise
from the documented ranges below, writes a synthetic recording (vibro_sim.synth) with its truth file
beside it, runs ``vibro analyze`` on the recording directory only (a separate process: the analysis
cannot see the truth or anything the synthesizer knows), then scores results.json against the truth:
confusion matrix, main-parameter errors, D before/after against the D the true model reaches on the
same data. PySINDy (if installed) gets the same measured data and is scored the same way.

Documented ranges (SI; log-uniform for the force coefficients):

===============================  ==========================================================
coulomb_friction                 force_n 6e-5 .. 3e-4 N (3-17 % of the ball's weight)
viscous_drag                     coefficient_ns_per_m 1e-4 .. 5e-4
quadratic_drag                   coefficient_ns2_per_m2 2e-4 .. 1e-3
gravity_tilt                     tilt_deg 8 .. 30
structure_harmonics              h2_ratio 0.01 .. 0.06, h3_ratio 0 .. 0.03, phases uniform
asymmetric_restitution           cor_bottom 0.70 .. 0.78, cor_top 0.50 .. 0.66, cor_sigma 0.02 .. 0.05
                                 (the paper's Table 2: e_b 0.72-0.76, e_t 0.50-0.65, std 0.03-0.05)
velocity_dependent_restitution   cor_at_zero 0.82 .. 0.95, slope_s_per_m 0.10 .. 0.30
excitation                       frequency 20 .. 24 Hz, acceleration amplitude 25 .. 32 m/s^2
                                 (two impacts per cycle: bench/bench_sim.py --regime)
image noise                      read noise 1 .. 4 gray levels (``Draws.noise_gray``)
===============================  ==========================================================

Out of the catalogue (the rig's invented effects, vibro_sim/synth/invented.py; the analysis must report
them as ``unexplained``, located), T the recording's duration:

===============================  ==========================================================
cor_drift                        the COR changes by 0.05 .. 0.15 over T, either sign
                                 (drift_per_s = change / T; detectable from ~1000 frames on:
                                 ~45 impacts of 0.015 scatter give the trend an sd of 0.008)
structure_tone                   tone_amplitude_um 5 .. 30, tone_frequency_hz 5 .. 15, phase uniform
plate_step                       step_um 30 .. 100; step_time_s uniform over the middle 30-70 % of T
                                 keeping 4 drive cycles either side (T / 2 when T is too short)
plate_creep                      the upper plate creeps 10 .. 60 um/s against the structure, either sign
position_force                   weight_fraction 0.1 .. 0.3 at the lower plate, decay_mm 1.5 .. 5
cor_parity                       the lower plate's COR alternates on successive impacts between two
                                 values 0.08 .. 0.16 apart around 0.62 .. 0.72 (either one first)
===============================  ==========================================================

Two ways to draw (``Draws``):

* ``magnitudes = 0`` (default, ``vibro prove --cases N``): cases cycle through the seven effects and the
  control in a shuffled order, so N >= 8 covers all; every parameter drawn from its full range.
* ``magnitudes = M`` (``--magnitudes M``; ``--evidence`` is the ``EVIDENCE`` set): each catalogue family (and
  each invented one with ``--invented``) at M magnitudes (the main parameter's range cut in M equal
  parts, log for the forces, drawn within part k; part M-1 the strongest), plus ``controls`` controls, in
  a shuffled order.

Either way each case also draws its per-impact COR scatter (uniform in ``Draws.cor_scatter``, the
synth's ``--cor-scatter``), its noise (``Draws.noise_gray``) and motion blur (probability
``Draws.blur_share``, the synth's ``--blur``: 0.5 ms exposure); scatter and blur come from a stream
separate from the legacy draws, so that ``--cases`` runs without them draw what they drew before.

Harder rigs (``vibro prove --harder [--cases N] [--frames N] [--seed S]``, :mod:`.harder`): a separate set
drawn by the same generator, the families of the issue on harder rigs: near-chatter with sticking (baseline
COR 0.4 .. 0.6 at 9 .. 11 Hz and 12 .. 14 m/s^2; a control), runs of 2 .. 6 deleted frame files hiding an
impact on either plate or inside a flight, on recordings with and without accelerometers (a control, and with
Coulomb friction), ``position_force`` and ``cor_parity`` (out of the catalogue), a plain control: 13 cases of
1000 frames by default, read noise 1 .. 4 gray levels, motion blur on about half. Scored per case, one table
row each with pass/FAIL per criterion: impact recall over the measurable impacts (short hops included) >= 98 %,
no invented impact, every impact inside a gap found
(``in_gap``, time and COR within 4 of their sigmas) or counted by the gap's verdict, mean |COR error| <= 0.002,
findings against the truth (controls: no catalogue finding; out of the catalogue: ``unexplained`` on top), D_r
lowered by every correct catalogue finding; PySINDy's findings beside.

Scored per case (:mod:`.truth`): effects identified (an out-of-catalogue effect only as ``unexplained``
with a location; ``located``: its mismatches where the truth has it), spurious findings (anything on a
control), each correct finding's restarted deviation D_r before/after (improved: D_r lowered; a COR
law, which D_r cannot see, explains a share of the COR variance above chance) beside the paper's D,
the per-impact COR error against the truth's realised CORs (``cor``: the final model's; ``cor_paper``: the
paper's Eq. 16) over the impacts matched by time, the contact scatter reported against the drawn one.

D of the true model (the goal's reference, "on the same noisy data"): the truth's laws and parameters
(COR scatter left out: no law predicts it) and the true structure motion, replayed exactly as the
analysis replays its own model, from the flight state and plate levels measured from the recording with
the true laws (:func:`.truth.true_model_measured_run`). Also reported: the true model from the true state
(an oracle without measurement error; weakly stable regimes amplify any initial error, see the bench).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vibro_discrepancy.data import measured_from_document
from vibro_discrepancy.library import EFFECTS
from vibro_fit.identify import identify
from vibro_fit.results import results_model
from vibro_io.dictrack import read_dic_csv
from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError
from vibro_sim.synth import SynthConfig, synthesize, truth_path
from vibro_sim.synth.invented import INVENTED_EFFECTS

from .sindy_baseline import available, sindy_discrepancy
from .truth import (
    cor_errors,
    finding_deviations,
    relative,
    score_case,
    true_model_measured_run,
    true_model_restarted_run,
    true_model_run,
)

CONTROL = "none"
FAMILIES = EFFECTS + (CONTROL,)
INVENTED = tuple(INVENTED_EFFECTS)
UNEXPLAINED = "unexplained"
GOALS = {"identified_pct": 95.0, "control_findings": 0, "parameter_error_pct": 15.0, "d_ratio": 1.5,
         "cor_error_effects": 0.002, "cor_error_controls": 0.001}


@dataclass(frozen=True)
class Draws:
    """How cases are drawn besides the effect (module docstring). Ranges are (low, high), inclusive."""

    cor_scatter: tuple[float, float] = (0.0, 0.0)
    noise_gray: tuple[float, float] = (1.0, 4.0)
    blur_share: float = 0.0
    magnitudes: int = 0
    controls: int = 3
    catalogue: tuple[str, ...] = EFFECTS
    invented: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        def rng_ok(r, lo, hi):
            return len(r) == 2 and lo <= r[0] <= r[1] <= hi
        if not rng_ok(self.cor_scatter, 0.0, 0.3):
            raise RecordingError(f"--cor-scatter must be LOW[,HIGH] with 0 <= LOW <= HIGH <= 0.3, "
                                 f"got {self.cor_scatter}")
        if not rng_ok(self.noise_gray, 0.0, 50.0):
            raise RecordingError(f"--noise must be LOW,HIGH gray levels with 0 <= LOW <= HIGH <= 50, "
                                 f"got {self.noise_gray}")
        if not 0.0 <= self.blur_share <= 1.0:
            raise RecordingError(f"--blur-share must be in [0, 1], got {self.blur_share}")
        if not 0 <= self.magnitudes <= 10:
            raise RecordingError(f"--magnitudes must be in 0..10, got {self.magnitudes}")
        if self.controls < 0:
            raise RecordingError(f"--controls must be >= 0, got {self.controls}")
        bad = [f for f in self.catalogue if f not in EFFECTS] + [f for f in self.invented if f not in INVENTED]
        if bad:
            raise RecordingError(f"unknown effect families {bad}: catalogue {list(EFFECTS)}, invented {list(INVENTED)}")


#: The evidence set of ``--evidence``: COR scatter 0.01-0.02, noise 1-3 gray levels, blur on half the cases, every
#: catalogue effect at two magnitudes, three controls, the three invented effects at two magnitudes
EVIDENCE = Draws(cor_scatter=(0.01, 0.02), noise_gray=(1.0, 3.0), blur_share=0.5, magnitudes=2, controls=3,
                 invented=INVENTED)


@dataclass(kw_only=True)
class CaseSpec:
    index: int
    family: str
    effects: dict
    seed: int
    frequency_hz: float
    accel_mps2: float
    noise_gray: float
    frames: int
    cor_scatter: float = 0.0
    blur: bool = False
    magnitude: int | None = None      # part of the main parameter's range (0 weakest), None: full range


def _logu(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _value(rng: np.random.Generator, lo: float, hi: float, u: float | None, log: bool = False) -> float:
    """Drawn from [lo, hi] (log-uniform if ``log``) when ``u`` is None, else the point at fraction ``u``."""
    if u is None:
        return _logu(rng, lo, hi) if log else float(rng.uniform(lo, hi))
    if log:
        return float(math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))))
    return float(lo + u * (hi - lo))


def _step_time_s(rng: np.random.Generator, duration_s: float, frequency_hz: float) -> float:
    lo, hi = max(0.3 * duration_s, 4.0 / frequency_hz), min(0.7 * duration_s, duration_s - 4.0 / frequency_hz)
    return float(rng.uniform(lo, hi)) if hi > lo else 0.5 * duration_s


def draw_effect(family: str, rng: np.random.Generator, u: float | None = None, duration_s: float = 1.0,
                frequency_hz: float = 22.0) -> dict:
    """Parameters of ``family`` drawn from the documented ranges (module docstring); with ``u`` in [0, 1]
    the main parameter sits at that fraction of its range (1 the strongest effect), the others drawn.
    ``duration_s`` and ``frequency_hz`` (the recording's) place the invented effects."""
    if family == CONTROL:
        return {}
    if family == "coulomb_friction":
        return {family: {"force_n": _value(rng, 6e-5, 3e-4, u, log=True)}}
    if family == "viscous_drag":
        return {family: {"coefficient_ns_per_m": _value(rng, 1e-4, 5e-4, u, log=True)}}
    if family == "quadratic_drag":
        return {family: {"coefficient_ns2_per_m2": _value(rng, 2e-4, 1e-3, u, log=True)}}
    if family == "gravity_tilt":
        return {family: {"tilt_deg": _value(rng, 8.0, 30.0, u)}}
    if family == "structure_harmonics":
        return {family: {"h2_ratio": _value(rng, 0.01, 0.06, u), "h3_ratio": float(rng.uniform(0.0, 0.03)),
                         "h2_phase_rad": float(rng.uniform(-math.pi, math.pi)),
                         "h3_phase_rad": float(rng.uniform(-math.pi, math.pi))}}
    if family == "asymmetric_restitution":
        # the strongest: the lowest top-plate COR
        return {family: {"cor_top": _value(rng, 0.50, 0.66, None if u is None else 1.0 - u),
                         "cor_bottom": float(rng.uniform(0.70, 0.78)),
                         "cor_sigma": float(rng.uniform(0.02, 0.05))}}
    if family == "velocity_dependent_restitution":
        return {family: {"cor_at_zero": float(rng.uniform(0.82, 0.95)), "slope_s_per_m": _value(rng, 0.10, 0.30, u)}}
    if family == "cor_drift":
        change = _value(rng, 0.05, 0.15, u) * (1.0 if rng.random() < 0.5 else -1.0)
        return {family: {"drift_per_s": change / duration_s}}
    if family == "structure_tone":
        return {family: {"tone_amplitude_um": _value(rng, 5.0, 30.0, u, log=True),
                         "tone_frequency_hz": float(rng.uniform(5.0, 15.0)),
                         "tone_phase_rad": float(rng.uniform(-math.pi, math.pi))}}
    if family == "plate_step":
        return {family: {"step_um": _value(rng, 30.0, 100.0, u),
                         "step_time_s": _step_time_s(rng, duration_s, frequency_hz)}}
    if family == "plate_creep":
        rate = _value(rng, 10.0, 60.0, u) * (1.0 if rng.random() < 0.5 else -1.0)
        return {family: {"creep_um_per_s": rate}}
    if family == "position_force":
        return {family: {"weight_fraction": _value(rng, 0.1, 0.3, u), "decay_mm": float(rng.uniform(1.5, 5.0))}}
    if family == "cor_parity":
        mid, half = float(rng.uniform(0.62, 0.72)), 0.5 * _value(rng, 0.08, 0.16, u)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return {family: {"cor_even": mid - sign * half, "cor_odd": mid + sign * half}}
    raise ValueError(f"unknown effect family {family!r}")


_FORCES = ("coulomb_friction", "viscous_drag", "quadratic_drag")
_RESTITUTION = ("asymmetric_restitution", "velocity_dependent_restitution")


def _compatible(a: str, b: str) -> bool:
    """The synthetic rig takes at most one force law and one COR law."""
    return a != b and not (a in _FORCES and b in _FORCES) and not (a in _RESTITUTION and b in _RESTITUTION)


def _extras(specs: list[CaseSpec], seed: int, draws: Draws) -> list[CaseSpec]:
    """COR scatter and blur per case, from their own stream (the legacy draws stay as they were)."""
    rng = np.random.default_rng([seed, 13])
    for s in specs:
        s.cor_scatter = float(rng.uniform(*draws.cor_scatter))
        s.blur = bool(rng.random() < draws.blur_share)
    return specs


def draw_cases(n: int, seed: int, frames: int, pairs: float = 0.0, draws: Draws = Draws(),
               fps: float = 1000.0) -> list[CaseSpec]:
    """``n`` cases: families in shuffled cycles of the 7 effects + control; everything else drawn. With
    probability ``pairs`` an effect case gets a second, compatible effect (family label "a+b")."""
    rng = np.random.default_rng(seed)
    fams: list[str] = []
    while len(fams) < n:
        cycle = list(FAMILIES)
        rng.shuffle(cycle)
        fams += cycle
    out = []
    for i, fam in enumerate(fams[:n]):
        effects = draw_effect(fam, rng)
        label = fam
        if fam != CONTROL and pairs > 0 and rng.random() < pairs:
            other = [f for f in EFFECTS if _compatible(fam, f)]
            second = str(rng.choice(other))
            effects.update(draw_effect(second, rng))
            label = f"{fam}+{second}"
        out.append(CaseSpec(index=i, family=label, effects=effects, seed=int(rng.integers(0, 2 ** 31 - 1)),
                            frequency_hz=float(rng.uniform(20.0, 24.0)), accel_mps2=float(rng.uniform(25.0, 32.0)),
                            noise_gray=float(rng.uniform(*draws.noise_gray)), frames=frames))
    return _extras(out, seed, draws)


def draw_evidence(seed: int, frames: int, draws: Draws = EVIDENCE, pairs: float = 0.0,
                  fps: float = 1000.0) -> list[CaseSpec]:
    """Every family of ``draws.catalogue`` and ``draws.invented`` at ``draws.magnitudes`` magnitudes
    (part k of M of the main parameter's range) and ``draws.controls`` controls, shuffled; ``pairs`` as in
    :func:`draw_cases` (catalogue cases only; the second effect from its full range)."""
    m = max(draws.magnitudes, 1)
    plan = [(f, k) for f in draws.catalogue + draws.invented for k in range(m)] + [(CONTROL, None)] * draws.controls
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(plan))
    out = []
    for i, j in enumerate(order):
        fam, k = plan[int(j)]
        f_hz, a_mps2 = float(rng.uniform(20.0, 24.0)), float(rng.uniform(25.0, 32.0))
        u = None if k is None else (k + float(rng.uniform())) / m
        effects = draw_effect(fam, rng, u, frames / fps, f_hz)
        label = fam
        if fam in EFFECTS and pairs > 0 and rng.random() < pairs:
            second = str(rng.choice([f for f in EFFECTS if _compatible(fam, f)]))
            effects.update(draw_effect(second, rng))
            label = f"{fam}+{second}"
        out.append(CaseSpec(index=i, family=label, effects=effects, seed=int(rng.integers(0, 2 ** 31 - 1)),
                            frequency_hz=f_hz, accel_mps2=a_mps2, noise_gray=float(rng.uniform(*draws.noise_gray)),
                            frames=frames, magnitude=k))
    return _extras(out, seed, draws)


def _vibro_command() -> list[str]:
    """The ``vibro`` CLI: the repo's entry script when present, else this interpreter's module."""
    root = os.environ.get("VIBRO_ROOT") or str(Path(__file__).resolve().parents[4])
    script = Path(root) / "vibro"
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-m", "vibro_app.cli"]


def paper_measured(track, rig):
    """What the discrepancy analysis saw: the identification's (paper Eq. 15-16) results of ``track``,
    before the re-identification with the final model replaced the impacts in results.json. PySINDy and
    the true model are given this, as the analysis was (not the analysis' own corrected impacts)."""
    return measured_from_document(results_model(identify(track, rig), "prove"), track, rig)


def _contact_scatter(disc: dict, spec: CaseSpec) -> dict:
    """The analysis' random contact scatter beside the drawn one (asymmetric_restitution's own cor_sigma
    adds in quadrature, as in the synth)."""
    own = spec.effects.get("asymmetric_restitution", {}).get("cor_sigma", 0.0)
    allp = (disc.get("contact_scatter") or {}).get("all") or {}
    return {"sigma": allp.get("sigma"), "true_sigma": math.hypot(spec.cor_scatter, own),
            "noise_sigma": allp.get("noise_sigma"), "exceeds_noise": allp.get("exceeds_noise")}


def run_case(spec: CaseSpec, work: Path, sindy: bool = True) -> dict:
    """Synthesize, analyze (CLI, recording only), score. Returns one row of the proof."""
    rec = work / f"case{spec.index:03d}"
    out = work / f"case{spec.index:03d}_out"
    cfg = SynthConfig(effects=spec.effects, seed=spec.seed, frequency_hz=spec.frequency_hz, accel_mps2=spec.accel_mps2,
                      noise_gray=spec.noise_gray, frames=spec.frames, accel=False, cor_scatter=spec.cor_scatter,
                      blur=spec.blur)
    t0 = time.perf_counter()
    synthesize(rec, cfg, overwrite=True, progress=False)
    t_synth = time.perf_counter() - t0
    t0 = time.perf_counter()
    proc = subprocess.run(_vibro_command() + ["analyze", str(rec), "--out", str(out), "--no-progress", "--overwrite",
                                              "--no-report"], capture_output=True, text=True)
    t_an = time.perf_counter() - t0
    row: dict[str, Any] = {"case": spec.index, "family": spec.family, "spec": asdict(spec),
                           "seconds": {"synth": t_synth, "analyze": t_an}}
    if proc.returncode != 0:
        row["error"] = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["analyze failed"]
        return row
    # scoring: only now is the truth read
    truth = json.loads(truth_path(rec).read_text())
    doc = json.loads((out / "results.json").read_text())
    disc = doc["discrepancy"]
    row["found"] = [f["effect"] for f in disc.get("findings", [])]
    row["score"] = score_case(disc, truth)
    row["findings"] = finding_deviations(disc, truth, sum(i.get("cor") is not None for i in doc.get("impacts", [])))
    row["cor_error"] = cor_errors(doc.get("impacts", []), truth)
    row["cor_method"] = (doc.get("impacts_model") or {}).get("cor_method")
    row["contact_scatter"] = _contact_scatter(disc, spec)
    row["regime"] = doc.get("regime", {}).get("name")
    meas = paper_measured(read_dic_csv(out / "dic.csv"), load_rig(rec / "rig.yaml"))
    d_true = d_oracle = dr_true = None
    try:
        d_true = true_model_measured_run(meas, truth).deviation
        dr_true = true_model_restarted_run(meas, truth).deviation
        if disc.get("replay_start_s") is not None:
            _, _, d_oracle = true_model_run(meas, truth, float(disc["replay_start_s"]))
    except Exception as exc:  # noqa: BLE001
        row["true_model_error"] = str(exc)
    # final/baseline are the restarted D_r (compared with the true model's D_r); paper_* the paper's
    # free-running D (compared with the true model's D, and from the true state)
    paper_final = disc.get("paper_final_deviation", disc.get("final_deviation"))
    row["deviation"] = {"baseline": disc.get("baseline_deviation"), "final": disc.get("final_deviation"),
                        "true_model_restarted": dr_true,
                        "final_over_true_restarted": relative(disc.get("final_deviation"), dr_true),
                        "baseline_over_true_restarted": relative(disc.get("baseline_deviation"), dr_true),
                        "paper_baseline": disc.get("paper_baseline_deviation"), "paper_final": paper_final,
                        "true_model": d_true, "final_over_true": relative(paper_final, d_true),
                        "true_model_from_true_state": d_oracle,
                        "final_over_true_from_true_state": relative(paper_final, d_oracle)}
    if "error" in disc:
        row["analysis_error"] = disc["error"]
    if sindy:

        if available():
            try:
                s = sindy_discrepancy(meas)
                row["sindy"] = {"found": [f["effect"] for f in s["findings"]], "score": score_case(s, truth),
                                "deviation": {"baseline": s["baseline_deviation"], "final": s["final_deviation"],
                                              "final_over_true": relative(s["final_deviation"], d_true)}}
            except Exception as exc:  # noqa: BLE001
                row["sindy"] = {"error": f"{type(exc).__name__}: {exc}"}
    return row


def _is_invented(family: str) -> bool:
    return any(part in INVENTED for part in family.split("+"))


def _max(xs) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(max(xs)) if xs else None


def _median(xs) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.median(xs)) if xs else None


def summarize(rows: list[dict], who: str = "vibro") -> dict:
    """Confusion matrix (true family -> found effects, 'none' when nothing found), identification rate
    (catalogue and out-of-catalogue), control findings, parameter errors, D ratios, for ``who`` = "vibro"
    or "sindy"; for vibro also the per-impact COR error against the truth (effects / controls, final model
    and paper) and how many correct findings improved the model (:func:`.truth.finding_deviations`)."""
    truths = list(FAMILIES) + list(INVENTED)
    labels = list(FAMILIES) + [UNEXPLAINED]
    conf = {t: {f: 0 for f in labels} for t in truths}
    n_eff = n_ok = n_ctrl = n_ctrl_clean = n_spurious = n_inv = n_inv_ok = n_inv_located = 0
    perr, ratios, oracle, errors = [], [], [], 0
    cor_eff, cor_eff_p, cor_ctl, cor_ctl_p, unmatched = [], [], [], [], 0
    n_lowered = n_correct_findings = 0
    for r in rows:
        part = r if who == "vibro" else r.get("sindy")
        if not part or "score" not in part:
            errors += 1
            continue
        sc = part["score"]
        true_set = set(sc["true"])
        expected = {UNEXPLAINED if t in INVENTED else t for t in true_set}
        for t in (sc["true"] or [CONTROL]):
            # a pair case's row for t: t if found, plus anything found that is not expected ('none': missed)
            want = UNEXPLAINED if t in INVENTED else t
            mine = [f for f in sc["found"] if f == want or f not in expected] or [CONTROL]
            for f in mine:
                conf[t][f if f in labels else UNEXPLAINED] += 1
        if r["family"] == CONTROL:
            n_ctrl += 1
            n_ctrl_clean += int(not sc["found"])
        else:
            n_eff += len(sc["true"])
            n_ok += len(sc["correct"])
            n_spurious += len(sc["spurious"])
            inv = [t for t in sc["true"] if t in INVENTED]
            n_inv += len(inv)
            n_inv_ok += sum(t in sc["correct"] for t in inv)
            n_inv_located += sum(bool(sc.get("located", {}).get(t)) for t in inv)
            for pe in sc["parameter_errors"].values():
                perr.append(pe["relative_error"])
            q = part["deviation"].get("final_over_true")
            if q is not None and not inv:
                ratios.append(q)
            q = r.get("deviation", {}).get("final_over_true_from_true_state") if who == "vibro" else None
            if q is not None and not inv:
                oracle.append(q)
        if who == "vibro":
            ce = r.get("cor_error") or {}
            unmatched += ce.get("unmatched", 0)
            (cor_ctl if r["family"] == CONTROL else cor_eff).append(ce.get("max_abs"))
            (cor_ctl_p if r["family"] == CONTROL else cor_eff_p).append(ce.get("max_abs_paper"))
            for f in r.get("findings", []):
                if f["correct"] and f["measure"] is not None:   # unexplained: only with a model
                    n_correct_findings += 1
                    n_lowered += int(bool(f["lowered"]))
    perr_a = np.array(perr)
    rat = np.array(ratios)
    out = {
        "cases": len(rows), "failed_cases": errors,
        "effects": n_eff, "identified": n_ok, "identified_pct": 100.0 * n_ok / n_eff if n_eff else None,
        "out_of_catalogue": n_inv, "out_of_catalogue_unexplained": n_inv_ok,
        "out_of_catalogue_located": n_inv_located,
        "spurious_findings_on_effect_cases": n_spurious,
        "controls": n_ctrl, "controls_without_finding": n_ctrl_clean,
        "parameter_error_median_pct": float(100 * np.median(perr_a)) if perr_a.size else None,
        "parameter_error_max_pct": float(100 * np.max(perr_a)) if perr_a.size else None,
        "parameter_within_15pct": f"{int(np.sum(perr_a <= 0.15))}/{perr_a.size}",
        "d_final_over_true_median": float(np.median(rat)) if rat.size else None,
        "d_final_over_true_max": float(np.max(rat)) if rat.size else None,
        "d_within_1p5x_true": f"{int(np.sum(rat <= 1.5))}/{rat.size}",
        "d_final_over_true_from_true_state_median": float(np.median(oracle)) if oracle else None,
        "d_final_over_true_from_true_state_max": float(np.max(oracle)) if oracle else None,
        "confusion": conf,
    }
    if who == "vibro":
        out.update({"cor_error_max_effects": _max(cor_eff), "cor_error_max_effects_paper": _max(cor_eff_p),
                    "cor_error_max_controls": _max(cor_ctl), "cor_error_max_controls_paper": _max(cor_ctl_p),
                    "unmatched_impacts": unmatched, "correct_findings": n_correct_findings,
                    "correct_findings_improving": n_lowered, "families": family_table(rows)})
    return out


def family_table(rows: list[dict]) -> dict:
    """Per family (the case's label): cases, effects identified, out-of-catalogue located, max per-impact
    COR error vs the truth (final model; paper Eq. 16), medians of D_r before/after, the true model's D_r,
    the paper's D before/after."""
    fams: dict[str, list[dict]] = {}
    for r in rows:
        fams.setdefault(r["family"], []).append(r)
    out = {}
    for fam in sorted(fams, key=lambda f: (f == CONTROL, _is_invented(f), f)):
        rs = [r for r in fams[fam] if "score" in r]
        dev = [r.get("deviation", {}) for r in rs]
        judged = [f for r in rs for f in r.get("findings", []) if f["correct"] and f["measure"] is not None]
        out[fam] = {
            "cases": len(fams[fam]), "failed": len(fams[fam]) - len(rs),
            "identified": sum(len(r["score"]["correct"]) for r in rs),
            "effects": sum(len(r["score"]["true"]) for r in rs),
            "spurious": sum(len(r["score"]["spurious"]) for r in rs),
            "located": sum(sum(bool(v) for v in r["score"].get("located", {}).values()) for r in rs),
            "cor_error_max": _max((r.get("cor_error") or {}).get("max_abs") for r in rs),
            "cor_error_max_paper": _max((r.get("cor_error") or {}).get("max_abs_paper") for r in rs),
            "d_r_before": _median(d.get("baseline") for d in dev),
            "d_r_after": _median(d.get("final") for d in dev),
            "d_r_true": _median(d.get("true_model_restarted") for d in dev),
            "paper_d_before": _median(d.get("paper_baseline") for d in dev),
            "paper_d_after": _median(d.get("paper_final") for d in dev),
            "improved": f"{sum(bool(f['lowered']) for f in judged)}/{len(judged)}",
        }
    return out


def _g(x) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def format_family_table(fams: dict) -> str:
    """The per-family table (D in %, COR error in 1e-3)."""
    head = (f"   {'family':32} {'ident':>6} {'spur':>4} {'COR err e-3':>11} {'paper e-3':>9} "
            f"{'D_r bef %':>9} {'D_r aft %':>9} {'D_r true%':>9} {'improved':>8} {'D bef %':>8} {'D aft %':>8}")
    lines = [head]

    def pct(x):
        return "n/a" if x is None else f"{100 * x:.3g}"

    def milli(x):
        return "n/a" if x is None else f"{1000 * x:.3g}"
    for fam, v in fams.items():
        ident = f"{v['identified']}/{v['effects']}" if v["effects"] else "-"
        if _is_invented(fam):
            ident += f" L{v['located']}"
        lines.append(f"   {fam[:32]:32} {ident:>6} {v['spurious']:>4} {milli(v['cor_error_max']):>11} "
                     f"{milli(v['cor_error_max_paper']):>9} {pct(v['d_r_before']):>9} {pct(v['d_r_after']):>9} "
                     f"{pct(v['d_r_true']):>9} {v['improved']:>8} {pct(v['paper_d_before']):>8} "
                     f"{pct(v['paper_d_after']):>8}")
    return "\n".join(lines)


def format_summary(s: dict, title: str) -> str:
    lines = [f"== {title}: {s['cases']} cases ({s['failed_cases']} failed)",
             f"   effects identified   {s['identified']}/{s['effects']}"
             + (f" = {s['identified_pct']:.1f} %" if s["identified_pct"] is not None else "")]
    if s.get("out_of_catalogue"):
        n_inv = s["out_of_catalogue"]
        lines.append(f"   out of catalogue     {s['out_of_catalogue_unexplained']}/{n_inv} unexplained, "
                     f"{s['out_of_catalogue_located']}/{n_inv} located where the truth has them")
    lines += [f"   spurious findings    {s['spurious_findings_on_effect_cases']} (on effect cases)",
              f"   controls clean       {s['controls_without_finding']}/{s['controls']}",
              f"   main parameter error median {_g(s['parameter_error_median_pct'])} %, max "
              f"{_g(s['parameter_error_max_pct'])} %, within 15 %: {s['parameter_within_15pct']}",
              f"   D final / D true     median {_g(s['d_final_over_true_median'])}, max "
              f"{_g(s['d_final_over_true_max'])}, within 1.5x: {s['d_within_1p5x_true']}"]
    if "cor_error_max_effects" in s:
        lines += [f"   COR error vs truth   effects max {_g(s['cor_error_max_effects'])} (paper Eq. 16: "
                  f"{_g(s['cor_error_max_effects_paper'])}), controls max {_g(s['cor_error_max_controls'])} "
                  f"(paper {_g(s['cor_error_max_controls_paper'])}); unmatched impacts {s['unmatched_impacts']}",
                  f"   findings improving   {s['correct_findings_improving']}/{s['correct_findings']} (correct "
                  "catalogue findings and modelled unexplained ones: D_r lower; COR laws: COR variance share "
                  "above chance)"]
    lines.append("   confusion (rows: truth, columns: found)")
    truths = list(FAMILIES) + list(INVENTED)
    cols = [c for c in list(FAMILIES) + [UNEXPLAINED] if any(s["confusion"][t][c] for t in truths)]
    short = {c: c.replace("_restitution", "_rest").replace("velocity_dependent", "vel_dep")[:14] for c in cols}
    lines.append("   " + " " * 32 + " ".join(f"{short[c]:>14}" for c in cols))
    for t in truths:
        if any(s["confusion"][t].values()):
            lines.append(f"   {t:32}" + " ".join(f"{s['confusion'][t][c]:>14d}" for c in cols))
    if s.get("families"):
        lines.append("   per family (COR error: max |cor - cor_true| over matched impacts; D_r restarted, D the "
                     "paper's; medians; L: located)")
        lines.append(format_family_table(s["families"]))
    return "\n".join(lines)


@dataclass(frozen=True, kw_only=True)
class ProofCases:
    """Which cases a proof draws and runs (:func:`prove`).

    Attributes
    ----------
    cases : int
        Cases drawn by :func:`draw_cases` (not used when ``draws.magnitudes`` > 0: :func:`draw_evidence`).
    seed : int
        Seed of the draw.
    frames : int
        Camera frames per synthetic recording.
    pairs : float
        Share of cases given a second, compatible effect (0..1).
    draws : Draws
        How cases are drawn besides the effect.
    only : tuple of int or None
        Run just these case numbers of the drawn set (each drawn exactly as in the whole set); None: all.
    """

    cases: int = 8
    seed: int = 0
    frames: int = 500
    pairs: float = 0.0
    draws: Draws = Draws()
    only: tuple[int, ...] | None = None


def prove(selection: ProofCases = ProofCases(), out: str | Path | None = None, *, sindy: bool = True,
          progress: bool = False) -> dict:
    """Run the proof of the cases ``selection`` picks; returns {"rows", "vibro", "sindy", "settings"}; writes
    proof.json into ``out`` (None: a new temporary folder). ``sindy``: run PySINDy on the same data too;
    ``progress``: a progress bar on stderr."""
    import tempfile

    from tqdm import tqdm

    cases, seed, frames = selection.cases, selection.seed, selection.frames
    pairs, draws, only = selection.pairs, selection.draws, selection.only
    if cases < 1:
        raise RecordingError(f"--cases must be >= 1, got {cases}")
    if frames < 200:
        raise RecordingError(f"--frames must be >= 200 (enough flights to fit), got {frames}")
    work = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="vibro_prove_"))
    work.mkdir(parents=True, exist_ok=True)
    specs = (draw_evidence(seed, frames, draws, pairs) if draws.magnitudes
             else draw_cases(cases, seed, frames, pairs, draws))
    if only is not None:
        missing = sorted(set(only) - {s.index for s in specs})
        if missing:
            raise RecordingError(f"case numbers {missing} are not in the drawn set (0..{len(specs) - 1})")
        specs = [s for s in specs if s.index in set(only)]
    if not specs:
        raise RecordingError("nothing to prove: no effect family and no control drawn")
    rows = []
    for spec in tqdm(specs, desc="prove", unit="case", disable=not progress, file=sys.stderr):
        rows.append(run_case(spec, work, sindy))

    result = {"settings": {"cases": len(specs), "seed": seed, "frames": frames, "pairs": pairs, "work_dir": str(work),
                           "only": None if only is None else sorted(only),
                           "draws": asdict(draws), "pysindy": available() if sindy else None},
              "goals": GOALS, "vibro": summarize(rows, "vibro"), "rows": rows}
    if sindy and available():
        result["sindy"] = summarize(rows, "sindy")
    (work / "proof.json").write_text(json.dumps(result, indent=1, default=float), encoding="utf-8")
    return result
