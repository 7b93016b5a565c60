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
image noise                      read noise 1 .. 4 gray levels
===============================  ==========================================================

Cases cycle through the seven effects and the control in a shuffled order, so N >= 8 covers all.

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

from vibro_io.errors import RecordingError

from vibro_sim.discrepancy.library import EFFECTS

CONTROL = "none"
FAMILIES = EFFECTS + (CONTROL,)
GOALS = {"identified_pct": 95.0, "control_findings": 0, "parameter_error_pct": 15.0, "d_ratio": 1.5}


@dataclass
class CaseSpec:
    index: int
    family: str
    effects: dict
    seed: int
    frequency_hz: float
    accel_ms2: float
    noise_gray: float
    frames: int


def _logu(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw_effect(family: str, rng: np.random.Generator) -> dict:
    """Parameters of ``family`` drawn from the documented ranges (module docstring)."""
    if family == CONTROL:
        return {}
    if family == "coulomb_friction":
        return {family: {"force_n": _logu(rng, 6e-5, 3e-4)}}
    if family == "viscous_drag":
        return {family: {"coefficient_ns_per_m": _logu(rng, 1e-4, 5e-4)}}
    if family == "quadratic_drag":
        return {family: {"coefficient_ns2_per_m2": _logu(rng, 2e-4, 1e-3)}}
    if family == "gravity_tilt":
        return {family: {"tilt_deg": float(rng.uniform(8.0, 30.0))}}
    if family == "structure_harmonics":
        return {family: {"h2_ratio": float(rng.uniform(0.01, 0.06)), "h3_ratio": float(rng.uniform(0.0, 0.03)),
                         "h2_phase_rad": float(rng.uniform(-math.pi, math.pi)),
                         "h3_phase_rad": float(rng.uniform(-math.pi, math.pi))}}
    if family == "asymmetric_restitution":
        return {family: {"cor_top": float(rng.uniform(0.50, 0.66)), "cor_bottom": float(rng.uniform(0.70, 0.78)),
                         "cor_sigma": float(rng.uniform(0.02, 0.05))}}
    if family == "velocity_dependent_restitution":
        return {family: {"cor_at_zero": float(rng.uniform(0.82, 0.95)), "slope_s_per_m": float(rng.uniform(0.10, 0.30))}}
    raise ValueError(f"unknown effect family {family!r}")


_FORCES = ("coulomb_friction", "viscous_drag", "quadratic_drag")
_RESTITUTION = ("asymmetric_restitution", "velocity_dependent_restitution")


def _compatible(a: str, b: str) -> bool:
    """The synthetic rig takes at most one force law and one COR law."""
    return a != b and not (a in _FORCES and b in _FORCES) and not (a in _RESTITUTION and b in _RESTITUTION)


def draw_cases(n: int, seed: int, frames: int, pairs: float = 0.0) -> list[CaseSpec]:
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
        out.append(CaseSpec(i, label, effects, int(rng.integers(0, 2 ** 31 - 1)),
                            float(rng.uniform(20.0, 24.0)), float(rng.uniform(25.0, 32.0)),
                            float(rng.uniform(1.0, 4.0)), frames))
    return out


def _vibro_command() -> list[str]:
    """The ``vibro`` CLI: the repo's entry script when present, else this interpreter's module."""
    root = os.environ.get("VIBRO_ROOT") or str(Path(__file__).resolve().parents[4])
    script = Path(root) / "vibro"
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-m", "vibro_bringup.cli"]


def run_case(spec: CaseSpec, work: Path, sindy: bool = True) -> dict:
    """Synthesize, analyze (CLI, recording only), score. Returns one row of the proof."""
    from vibro_io.dictrack import read_dic_csv
    from vibro_io.rig import load_rig

    from vibro_sim.synth import SynthConfig, synthesize, truth_path
    from vibro_model.codec import read_results
    from vibro_sim.discrepancy.data import measured_from_document
    from .truth import relative, score_case, true_model_measured_run, true_model_restarted_run, true_model_run

    rec = work / f"case{spec.index:03d}"
    out = work / f"case{spec.index:03d}_out"
    cfg = SynthConfig(effects=spec.effects, seed=spec.seed, frequency_hz=spec.frequency_hz, accel_ms2=spec.accel_ms2,
                      noise_gray=spec.noise_gray, frames=spec.frames, accel=False)
    t0 = time.perf_counter()
    synthesize(rec, cfg, overwrite=True, progress=False)
    t_synth = time.perf_counter() - t0
    t0 = time.perf_counter()
    proc = subprocess.run(_vibro_command() + ["analyze", str(rec), "--out", str(out), "--no-progress", "--overwrite"],
                          capture_output=True, text=True)
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
    row["regime"] = doc.get("regime", {}).get("name")
    meas = measured_from_document(read_results(out / "results.json"), read_dic_csv(out / "dic.csv"),
                                  load_rig(rec / "rig.yaml"))
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
                        "paper_baseline": disc.get("paper_baseline_deviation"), "paper_final": paper_final,
                        "true_model": d_true, "final_over_true": relative(paper_final, d_true),
                        "true_model_from_true_state": d_oracle,
                        "final_over_true_from_true_state": relative(paper_final, d_oracle)}
    if "error" in disc:
        row["analysis_error"] = disc["error"]
    if sindy:
        from .sindy_baseline import available, sindy_discrepancy

        if available():
            try:
                s = sindy_discrepancy(meas)
                row["sindy"] = {"found": [f["effect"] for f in s["findings"]], "score": score_case(s, truth),
                                "deviation": {"baseline": s["baseline_deviation"], "final": s["final_deviation"],
                                              "final_over_true": relative(s["final_deviation"], d_true)}}
            except Exception as exc:  # noqa: BLE001
                row["sindy"] = {"error": f"{type(exc).__name__}: {exc}"}
    return row


def summarize(rows: list[dict], who: str = "vibro") -> dict:
    """Confusion matrix (true family -> found effects, 'none' when nothing found), identification rate,
    control findings, parameter errors, D ratios, for ``who`` = "vibro" or "sindy"."""
    labels = list(FAMILIES) + ["unexplained"]
    conf = {t: {f: 0 for f in labels} for t in FAMILIES}
    n_eff = n_ok = n_ctrl = n_ctrl_clean = n_spurious = 0
    perr, ratios, oracle, errors = [], [], [], 0
    for r in rows:
        part = r if who == "vibro" else r.get("sindy")
        if not part or "score" not in part:
            errors += 1
            continue
        sc = part["score"]
        true_set = set(sc["true"])
        for t in (sc["true"] or [CONTROL]):
            # a pair case's row for t: t if found, plus anything found that is not true ('none': missed)
            mine = [f for f in sc["found"] if f == t or f not in true_set] or [CONTROL]
            for f in mine:
                conf[t][f if f in labels else "unexplained"] += 1
        if r["family"] == CONTROL:
            n_ctrl += 1
            n_ctrl_clean += int(not sc["found"])
        else:
            n_eff += len(sc["true"])
            n_ok += len(sc["correct"])
            n_spurious += len(sc["spurious"])
            for pe in sc["parameter_errors"].values():
                perr.append(pe["relative_error"])
            q = part["deviation"].get("final_over_true")
            if q is not None:
                ratios.append(q)
            q = r.get("deviation", {}).get("final_over_true_from_true_state") if who == "vibro" else None
            if q is not None:
                oracle.append(q)
    perr_a = np.array(perr)
    rat = np.array(ratios)
    return {
        "cases": len(rows), "failed_cases": errors,
        "effects": n_eff, "identified": n_ok, "identified_pct": 100.0 * n_ok / n_eff if n_eff else None,
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


def _g(x) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def format_summary(s: dict, title: str) -> str:
    lines = [f"== {title}: {s['cases']} cases ({s['failed_cases']} failed)",
             f"   effects identified   {s['identified']}/{s['effects']}"
             + (f" = {s['identified_pct']:.1f} %" if s["identified_pct"] is not None else ""),
             f"   spurious findings    {s['spurious_findings_on_effect_cases']} (on effect cases)",
             f"   controls clean       {s['controls_without_finding']}/{s['controls']}",
             f"   main parameter error median {_g(s['parameter_error_median_pct'])} %, max "
             f"{_g(s['parameter_error_max_pct'])} %, within 15 %: {s['parameter_within_15pct']}",
             f"   D final / D true     median {_g(s['d_final_over_true_median'])}, max "
             f"{_g(s['d_final_over_true_max'])}, within 1.5x: {s['d_within_1p5x_true']}",
             "   confusion (rows: truth, columns: found)"]
    cols = [c for c in list(FAMILIES) + ["unexplained"] if any(s["confusion"][t][c] for t in FAMILIES)]
    short = {c: c.replace("_restitution", "_rest").replace("velocity_dependent", "vel_dep")[:14] for c in cols}
    lines.append("   " + " " * 32 + " ".join(f"{short[c]:>14}" for c in cols))
    for t in FAMILIES:
        if any(s["confusion"][t].values()):
            lines.append(f"   {t:32}" + " ".join(f"{s['confusion'][t][c]:>14d}" for c in cols))
    return "\n".join(lines)


def prove(cases: int = 8, seed: int = 0, out: str | Path | None = None, frames: int = 500, sindy: bool = True,
          progress: bool = False, pairs: float = 0.0) -> dict:
    """Run the proof; returns {"rows", "vibro", "sindy", "settings"}; writes proof.json into ``out``."""
    import tempfile

    from tqdm import tqdm

    if cases < 1:
        raise RecordingError(f"--cases must be >= 1, got {cases}")
    if frames < 200:
        raise RecordingError(f"--frames must be >= 200 (enough flights to fit), got {frames}")
    work = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="vibro_prove_"))
    work.mkdir(parents=True, exist_ok=True)
    specs = draw_cases(cases, seed, frames, pairs)
    rows = []
    for spec in tqdm(specs, desc="prove", unit="case", disable=not progress, file=sys.stderr):
        rows.append(run_case(spec, work, sindy))
    from .sindy_baseline import available

    result = {"settings": {"cases": cases, "seed": seed, "frames": frames, "pairs": pairs, "work_dir": str(work),
                           "pysindy": available() if sindy else None},
              "goals": GOALS, "vibro": summarize(rows, "vibro"), "rows": rows}
    if sindy and available():
        result["sindy"] = summarize(rows, "sindy")
    (work / "proof.json").write_text(json.dumps(result, indent=1, default=float), encoding="utf-8")
    return result
