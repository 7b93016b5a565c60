"""``vibro prove --harder``: the harder rigs, drawn by vibro's own generator and scored per case.

Families (``HARDER_FAMILIES``; the plan cycles through them in this order, so ``--cases N`` with N >= 6 covers
all; the default set ``HARDER_PLAN`` is 13 cases):

=====================  =====================================================================================
sticking               control: near-chatter with sticking on the lower plate. Baseline COR 0.40 .. 0.60
                       (the cases split the range in equal parts), drive 12 .. 14 m/s^2 at 9 .. 11 Hz (the
                       ball lands, hops 8 .. 2 ms and rides the plate until released), COR scatter 0.01
drops                  control with dropped frames: a regular recording (22 Hz family of ``vibro prove``), COR
                       scatter 0.01 .. 0.02, three runs of 2 .. 6 deleted frame files at least 30 frames apart:
                       one hiding an impact on each plate and one inside a flight; accelerometers on every
                       other case
drops+coulomb_friction the same drops on a recording with Coulomb friction (force_n 1e-4 .. 3e-4 N)
position_force         out of the catalogue: weight_fraction 0.15 .. 0.3, decay_mm 1.5 .. 5
cor_parity             out of the catalogue: the lower plate's COR alternates between two values 0.08 .. 0.16
                       apart around 0.62 .. 0.72, COR scatter 0.01
control                a regular recording without effect, COR scatter 0.01 .. 0.02
=====================  =====================================================================================

Read noise 1 .. 4 gray levels on every case, motion blur (0.5 ms exposure) on every other case of a family
(of the drops families: on all but the first, so that one case has both accelerometers and blur). The generator
knows the truth (it places the drops where the truth has impacts or none); ``vibro analyze`` runs on the
recording directory alone, in a separate process.

Scored per case (:func:`score_harder`), the criteria of ``HARDER_GOALS``:

- ``recall``: truth impacts matched by a reported impact of the same plate within one frame interval, over the
  *measurable* ones: outside every run of lost frames, with at least 3 frames present inside the flight on
  each side more than 0.3 frame interval from its ends (a frame that close may hold the contact in its
  exposure; short hops included); >= 98 %;
- ``invented``: reported impacts that match no truth impact (an ``in_gap`` one: of its plate within 4 of its
  time sigmas); 0;
- ``gaps``: per run of lost frames, ``found`` (the one impact inside reported ``in_gap`` within 4 time sigmas, its
  COR within 4 sigmas and 0.002), ``counted`` (no impact reported there and the identification's gap verdict says it
  may hide the true count) or ``lost``; a run inside a flight is ``clean`` when nothing is invented there and
  its verdict (if any) admits 0. Passes with no ``lost`` and no miscount;
- ``cor``: mean |COR - true COR| over the matched impacts with a COR; <= 0.002;
- ``findings``: a control has no catalogue finding; an out-of-catalogue case has ``unexplained`` and no
  catalogue finding above it; a catalogue case has its effect and no other catalogue finding;
- ``improved``: on a catalogue effect case, every correct finding lowers D_r (:func:`.truth.finding_deviations`);
  on an out-of-catalogue case, the ``unexplained`` finding on top modelled its shape
  (:mod:`vibro_discrepancy.shape_model`) and the deviation fell with it (D_r for the position force, D_i for
  the COR parity). The row's ``shape_fit`` holds the shape model's parameters against the truth
  (:func:`.truth.shape_fit_vs_truth`: weight fraction and decay; the lower plate's two CORs), not scored.

PySINDy, when installed, gets the same measured data; its findings are shown beside (not scored).
"""

from __future__ import annotations

import json
import math
import subprocess
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vibro_discrepancy.library import EFFECTS
from vibro_io.dictrack import read_dic_csv
from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError
from vibro_sim.synth import SynthConfig, synthesize, truth_path

from .prove import _vibro_command, paper_measured
from .sindy_baseline import available, sindy_discrepancy
from .truth import finding_deviations, shape_fit_vs_truth

HARDER_FAMILIES = ("sticking", "drops", "drops+coulomb_friction", "position_force", "cor_parity", "control")
#: the default set: how many cases of each family
HARDER_PLAN = {"sticking": 3, "drops": 3, "drops+coulomb_friction": 2, "position_force": 2, "cor_parity": 2,
               "control": 1}
CONTROLS = ("sticking", "drops", "control")
INVENTED_HARDER = ("position_force", "cor_parity")
HARDER_GOALS = {"recall": 0.98, "invented": 0, "cor_error_mean": 0.002}
CRITERIA = ("recall", "invented", "gaps", "cor", "findings", "improved")

MARGIN = 0.3           # frame intervals: a frame this close to an impact may hold the contact
MIN_FRAMES = 3         # frames inside a flight for its impacts to be measurable
# an in-gap impact's time and COR agree with the truth within this many of its sigmas: the gap test's own agreement
# level (vibro_fit.gaps.K_SIGMA); a whole set scores ~20 gaps x 2 quantities, at 3 sigmas an honest sigma would
# fail one run in twenty
GAP_SIGMAS = 4.0
DROP_SPACING = 30      # frames between two runs of drops and from the recording's ends


@dataclass
class HarderSpec:
    index: int
    family: str
    seed: int
    frames: int
    frequency_hz: float
    accel_mps2: float
    noise_gray: float
    cor: float = 0.7
    cor_scatter: float = 0.0
    effects: dict = field(default_factory=dict)
    accel: bool = False
    blur: bool = False
    drops: int = 0        # runs of lost frames to place (the frames themselves: after the synthesis)


def _order(counts: dict[str, int]) -> list[str]:
    """Families interleaved: one of each in ``HARDER_FAMILIES`` order, again while any is left."""
    left = dict(counts)
    out = []
    while any(left.values()):
        for f in HARDER_FAMILIES:
            if left.get(f, 0) > 0:
                out.append(f)
                left[f] -= 1
    return out


def draw_harder(seed: int, frames: int, cases: int | None = None) -> list[HarderSpec]:
    """The harder set (module docstring): ``HARDER_PLAN``, or with ``cases`` the first ``cases`` of the
    families cycled in ``HARDER_FAMILIES`` order."""
    if cases is None:
        fams = _order(HARDER_PLAN)
    else:
        fams = [HARDER_FAMILIES[i % len(HARDER_FAMILIES)] for i in range(cases)]
    rng = np.random.default_rng([seed, 27])
    n_of = {f: fams.count(f) for f in set(fams)}
    k_of: dict[str, int] = {}
    out = []
    for i, fam in enumerate(fams):
        k = k_of.get(fam, 0)
        k_of[fam] = k + 1
        u = (k + float(rng.uniform())) / n_of[fam]      # stratified over the family's cases
        noise = float(rng.uniform(1.0, 4.0))
        s = HarderSpec(i, fam, int(rng.integers(0, 2 ** 31 - 1)), frames, float(rng.uniform(20.0, 24.0)),
                       float(rng.uniform(25.0, 32.0)), noise, cor_scatter=float(rng.uniform(0.01, 0.02)),
                       blur=k % 2 == 1)
        if fam == "sticking":
            s.cor, s.cor_scatter = 0.40 + 0.20 * u, 0.01
            s.frequency_hz, s.accel_mps2 = float(rng.uniform(9.0, 11.0)), float(rng.uniform(12.0, 14.0))
        elif fam.startswith("drops"):
            s.drops, s.accel, s.blur = 3, k % 2 == 0, k >= 1
            if fam.endswith("coulomb_friction"):
                s.effects = {"coulomb_friction": {"force_n": float(math.exp(math.log(1e-4) + u * math.log(3.0)))}}
        elif fam == "position_force":
            s.effects = {fam: {"weight_fraction": 0.15 + 0.15 * u, "decay_mm": float(rng.uniform(1.5, 5.0))}}
        elif fam == "cor_parity":
            mid, half = float(rng.uniform(0.62, 0.72)), 0.5 * (0.08 + 0.08 * u)
            lo_first = rng.random() < 0.5
            s.effects = {fam: {"cor_even": mid - half if lo_first else mid + half,
                               "cor_odd": mid + half if lo_first else mid - half}}
            s.cor_scatter = 0.01
        out.append(s)
    return out


# ---------------------------------------------------------------- drops
def _gap_bounds(first: int, count: int, fps: float) -> tuple[float, float]:
    """(s) the last present frame before a run of lost frames and the first after it."""
    return (first - 1) / fps, (first + count) / fps


def place_drops(truth: dict, n_runs: int, rng: np.random.Generator, fps: float) -> list[tuple[int, int]]:
    """``n_runs`` runs (first frame, count) of 2..6 lost frames, ``DROP_SPACING`` apart: run 0 hides one
    impact on the lower plate, run 1 one on the upper plate, run 2 sits inside a flight (no impact in it).
    A run that finds no place is left out."""
    n = len(truth["frames"]["t_s"])
    t_imp = np.array([float(i["t"]) for i in truth["impacts"]])
    plates = [i["plate"] for i in truth["impacts"]]
    runs: list[tuple[int, int]] = []

    def free(first, count):
        return (DROP_SPACING <= first and first + count + DROP_SPACING <= n
                and all(first + count + DROP_SPACING <= a or a + c + DROP_SPACING <= first for a, c in runs))

    def inside(first, count):
        lo, hi = _gap_bounds(first, count, fps)
        return int(np.sum((t_imp > lo) & (t_imp < hi)))

    for r in range(n_runs):
        count = int(rng.integers(2, 7))
        want_plate = ("bottom", "top", None)[r % 3]
        options = []
        if want_plate is None:
            for first in range(DROP_SPACING, n - DROP_SPACING - count):
                if free(first, count) and inside(first - 2, count + 4) == 0:   # 2 frames clear of any impact
                    options.append(first)
        else:
            for t, p in zip(t_imp, plates):
                if p != want_plate:
                    continue
                for first in range(int(math.floor(t * fps)) - count + 1, int(math.floor(t * fps)) + 1):
                    lo, hi = _gap_bounds(first, count, fps)
                    # the impact at least a quarter frame inside the gap, alone in it
                    if free(first, count) and lo + 0.25 / fps < t < hi - 0.25 / fps and inside(first, count) == 1:
                        options.append(first)
        if options:
            runs.append((int(rng.choice(options)), count))
    return sorted(runs)


def delete_frames(rec: Path, runs: list[tuple[int, int]]) -> None:
    names = sorted(p.name for p in (rec / "frames").iterdir())
    for first, count in runs:
        for k in range(first, first + count):
            (rec / "frames" / names[k]).unlink()


# ---------------------------------------------------------------- scoring
def measurable_impacts(truth: dict, lost: set[int], fps: float) -> list[int]:
    """Indices of the truth impacts the camera can measure (module docstring): not between the frames either
    side of a run of lost frames (those are scored as the gap's), with ``MIN_FRAMES`` present frames inside
    the flight on each side, more than ``MARGIN`` from its ends."""
    t_frames = np.asarray(truth["frames"]["t_s"], float)
    present = np.array([k not in lost for k in range(t_frames.size)])
    hidden = [(t_frames[k - 1], t_frames[k + 1]) for k in lost if 0 < k < t_frames.size - 1]
    tp = t_frames[present]
    m = MARGIN / fps

    def inside(a, b):
        return int(np.sum((tp > a + m) & (tp < b - m)))

    starts = {round(float(f["t_start"]), 9): f for f in truth["flights"]}
    ends = {round(float(f["t_end"]), 9): f for f in truth["flights"]}
    out = []
    for j, imp in enumerate(truth["impacts"]):
        t = float(imp["t"])
        if any(lo < t < hi for lo, hi in hidden):
            continue
        p, q = ends.get(round(t, 9)), starts.get(round(t, 9))
        if p is None or q is None or p["t_start"] < t_frames[0] or q["t_end"] > t_frames[-1]:
            continue
        if inside(p["t_start"], t) >= MIN_FRAMES and inside(t, q["t_end"]) >= MIN_FRAMES:
            out.append(j)
    return out


def _catalogue(found: list[str]) -> list[str]:
    return [f for f in found if f in EFFECTS]


def score_harder(spec: HarderSpec, runs: list[tuple[int, int]], doc: dict, truth: dict, fps: float) -> dict:
    """The case's criteria (module docstring) from results.json ``doc`` and the truth."""
    lost = {k for a, c in runs for k in range(a, a + c)}
    imps = truth["impacts"]
    tt = np.array([float(i["t"]) for i in imps])
    found = [x for x in doc.get("impacts", []) if x.get("t") is not None]
    matched, invented = _match_impacts(found, tt, np.array([i["plate"] for i in imps]), fps)
    meas = measurable_impacts(truth, lost, fps)
    hit = [j for j in meas if j in matched]
    verdicts = (doc.get("identification") or {}).get("gaps") or []
    gaps = [_score_gap(window, run, _TruthImpacts(imps, tt), found, matched, verdicts)
            for window, run in zip([_gap_bounds(a, c, fps) for a, c in runs], runs)]
    errs = [abs(float(x["cor"]) - float(imps[j]["cor"])) for j, x in matched.items() if x.get("cor") is not None]
    disc = doc.get("discrepancy") or {}
    names = [f["effect"] for f in disc.get("findings", [])]
    improved, devs, shape_fit = _improvement(spec, disc, truth, found, names)
    recall = len(hit) / len(meas) if meas else None
    mean_err = float(np.mean(errs)) if errs else None
    criteria = {
        "recall": recall is not None and recall >= HARDER_GOALS["recall"],
        "invented": len(invented) <= HARDER_GOALS["invented"],
        "gaps": all(g["outcome"] in ("found", "counted", "clean") for g in gaps),
        "cor": mean_err is not None and mean_err <= HARDER_GOALS["cor_error_mean"],
        "findings": _findings_ok(spec, names),
        "improved": improved,          # None: a control
    }
    return {"measurable": len(meas), "recalled": len(hit), "recall": recall,
            "missed_t": [float(tt[j]) for j in meas if j not in matched], "invented_t": invented,
            "gaps": gaps, "cor_error_mean": mean_err, "cor_error_max": float(max(errs)) if errs else None,
            "cor_n": len(errs), "found": names, "regime": (doc.get("regime") or {}).get("name"),
            "contacts": len(doc.get("contacts") or []), "truth_contacts": len(truth.get("contacts") or []),
            "finding_deviations": devs, "shape_fit": shape_fit,
            "deviation": {"baseline": disc.get("baseline_deviation"), "final": disc.get("final_deviation")},
            "criteria": criteria, "pass": all(v is not False for v in criteria.values())}


@dataclass(frozen=True)
class _TruthImpacts:
    """The truth's impacts (``records``) and their times (``t``, s)."""

    records: list[dict]
    t: np.ndarray


def _match_impacts(found: list[dict], tt: np.ndarray, plates: np.ndarray, fps: float
                   ) -> tuple[dict[int, dict], list[float]]:
    """Pair the reported impacts ``found`` with the truth's (times ``tt`` s, ``plates``): an in-gap impact by its
    sigma, any other within one frame interval (1 / ``fps`` s); each truth impact once. Returns ({truth index:
    reported impact}, times (s) of the reported impacts matching none)."""
    matched: dict[int, dict] = {}
    invented = []
    for x in found:
        t = float(x["t"])
        same = np.flatnonzero(plates == x["plate"])
        if same.size == 0:
            invented.append(t)
            continue
        j = int(same[np.argmin(np.abs(tt[same] - t))])
        tol = GAP_SIGMAS * float(x.get("t_std") or 0.0) if x.get("in_gap") else 1.0 / fps
        if abs(tt[j] - t) <= tol and j not in matched:
            matched[j] = x
        else:
            invented.append(t)
    return matched, invented


def _score_gap(window: tuple[float, float], run: tuple[int, int], truth: _TruthImpacts, found: list[dict],
               matched: dict[int, dict], verdicts: list[dict]) -> dict[str, Any]:
    """The row of one gap (frames ``run`` = (first, count) lost, times ``window`` s): what it hid, what was
    reported in it, and its outcome against the identification's gap ``verdicts``."""
    lo, hi = window
    tt = truth.t
    inside = [j for j in range(len(truth.records)) if lo < tt[j] < hi]
    in_gap = [x for x in found if x.get("in_gap") and lo < float(x["t"]) < hi]
    over = [v for v in verdicts if v["t_start"] < hi and v["t_end"] > lo]
    row: dict[str, Any] = {"first_frame": run[0], "lost_frames": run[1], "true_impacts": len(inside),
                           "true_t": [float(tt[j]) for j in inside], "reported_in_gap": len(in_gap)}
    if inside:
        row.update(_occupied_gap_outcome(inside, in_gap, over, matched, truth))
    else:
        admits_zero = all(v.get("determined") is False and v["may_hide_min"] == 0 for v in over)
        row["outcome"] = "clean" if not in_gap and admits_zero else "miscounted"
        if over:
            row["may_hide"] = [[v["may_hide_min"], v["may_hide_max"]] for v in over]
    return row


def _occupied_gap_outcome(inside: list[int], in_gap: list[dict], over: list[dict], matched: dict[int, dict],
                          truth: _TruthImpacts) -> dict[str, Any]:
    """The outcome of a gap that hid the truth impacts ``inside``: "found" (its one impact reported in it with a
    COR within its sigma), "counted" (an undetermined verdict ``over`` it admits the count) or "lost"."""
    out: dict[str, Any] = {}
    ok_found = False
    if len(inside) == 1 and len(in_gap) == 1 and matched.get(inside[0]) is in_gap[0]:
        x, truth_x = in_gap[0], truth.records[inside[0]]
        err = None if x.get("cor") is None else abs(float(x["cor"]) - float(truth_x["cor"]))
        cor_ok = (err is not None and x.get("cor_std") and err <= GAP_SIGMAS * float(x["cor_std"])
                  and err <= HARDER_GOALS["cor_error_mean"])
        ok_found = bool(cor_ok)
        out.update(t_error_s=float(x["t"]) - float(truth.t[inside[0]]), t_std_s=x.get("t_std"),
                   cor_error=None if x.get("cor") is None else float(x["cor"]) - float(truth_x["cor"]),
                   cor_std=x.get("cor_std"))
    if ok_found:
        out["outcome"] = "found"
        return out
    undet = [v for v in over if not v.get("determined")]
    counted = any(v["may_hide_min"] <= sum(v["t_start"] < t < v["t_end"] for t in truth.t) <= v["may_hide_max"]
                  for v in undet) and not in_gap
    out["outcome"] = "counted" if counted else "lost"
    if undet:
        out["may_hide"] = [[v["may_hide_min"], v["may_hide_max"]] for v in undet]
    return out


def _findings_ok(spec: HarderSpec, names: list[str]) -> bool:
    """The findings (effect ``names``, best first) are right: none for a control, "unexplained" first for an
    invented effect, else exactly the case's catalogue effects."""
    cat = _catalogue(names)
    if spec.family in CONTROLS:
        return not cat
    if spec.family in INVENTED_HARDER:
        return bool(names) and names[0] == "unexplained"
    return sorted(cat) == sorted(e for e in spec.effects if e in EFFECTS)


def _improvement(spec: HarderSpec, disc: dict, truth: dict, found: list[dict], names: list[str]
                 ) -> tuple[bool | None, list, dict | None]:
    """(whether the correct findings lowered the deviation (None: a control), the findings' deviations, the
    unexplained finding's shape against the truth (invented effects only, else None))."""
    true_cat = [e for e in spec.effects if e in EFFECTS]
    if true_cat:
        devs = finding_deviations(disc, truth, sum(x.get("cor") is not None for x in found))
        judged = [d for d in devs if d["correct"] and d["measure"] is not None]
        return bool(judged) and all(bool(d["lowered"]) for d in judged), devs, None
    if spec.family in INVENTED_HARDER:
        devs = finding_deviations(disc, truth, sum(x.get("cor") is not None for x in found))
        top = (disc.get("findings") or [None])[0]
        improved = bool(names and names[0] == "unexplained" and devs[0]["lowered"])
        return improved, devs, shape_fit_vs_truth(top, truth)
    return None, [], None


# ---------------------------------------------------------------- running
def run_harder_case(spec: HarderSpec, work: Path, sindy: bool = True) -> dict:
    """Synthesize, drop frames, analyze (CLI, recording only), score. One row of the proof."""
    rec = work / f"hard{spec.index:03d}"
    out = work / f"hard{spec.index:03d}_out"
    cfg = SynthConfig(effects=spec.effects, seed=spec.seed, frequency_hz=spec.frequency_hz, cor=spec.cor,
                      accel_mps2=spec.accel_mps2, noise_gray=spec.noise_gray, frames=spec.frames, accel=spec.accel,
                      cor_scatter=spec.cor_scatter, blur=spec.blur)
    t0 = time.perf_counter()
    synthesize(rec, cfg, overwrite=True, progress=False)
    truth = json.loads(truth_path(rec).read_text())
    runs = place_drops(truth, spec.drops, np.random.default_rng([spec.seed, 5]), cfg.fps) if spec.drops else []
    delete_frames(rec, runs)
    t_synth = time.perf_counter() - t0
    t0 = time.perf_counter()
    proc = subprocess.run(_vibro_command() + ["analyze", str(rec), "--out", str(out), "--no-progress", "--overwrite",
                                              "--no-report"], capture_output=True, text=True)
    row: dict[str, Any] = {"case": spec.index, "family": spec.family, "spec": asdict(spec),
                           "dropped": [list(r) for r in runs],
                           "seconds": {"synth": t_synth, "analyze": time.perf_counter() - t0}}
    if proc.returncode != 0:
        row["error"] = ((proc.stderr or proc.stdout).strip().splitlines() or ["analyze failed"])[-1]
        row["pass"] = False
        return row
    doc = json.loads((out / "results.json").read_text())
    row.update(score_harder(spec, runs, doc, truth, cfg.fps))
    if sindy:


        if available():
            try:
                s = sindy_discrepancy(paper_measured(read_dic_csv(out / "dic.csv"), load_rig(rec / "rig.yaml")))
                row["sindy"] = {"found": [f["effect"] for f in s["findings"]]}
            except Exception as exc:  # noqa: BLE001
                row["sindy"] = {"error": f"{type(exc).__name__}: {exc}"}
    return row


def _ab(spec: dict) -> str:
    """Accelerometers (a) and blur (b) of a case, '-' for neither."""
    return ("a" if spec.get("accel") else "") + ("b" if spec.get("blur") else "") or "-"


def _mark(v) -> str:
    return "-" if v is None else ("pass" if v else "FAIL")


def _shape_text(r: dict) -> str:
    """The shape model's parameters against the truth, fit/true ('-' without one)."""
    p = (r.get("shape_fit") or {}).get("parameters") or {}
    if "weight_fraction" in p:
        wf, L = p["weight_fraction"], p.get("decay_mm") or {"fit": float("nan"), "true": float("nan")}
        return f"wf {wf['fit']:.3f}/{wf['true']:.3f} L {L['fit']:.2f}/{L['true']:.2f}"
    if "cor_low" in p:
        return "cor " + " ".join(f"{p[k]['fit']:.3f}/{p[k]['true']:.3f}" for k in ("cor_low", "cor_high") if k in p)
    return "-"


def format_harder_table(rows: list[dict]) -> str:
    """One line per case: its numbers and pass/FAIL per criterion ('-': does not apply)."""
    head = (f"{'case':>4} {'family':22} {'nz':>3} {'a/b':>3} {'drops':>11} {'recall':>11} {'R':>4} {'inv':>3} {'I':>4} "
            f"{'gaps F/C/K/L':>12} {'G':>4} {'COR e-3':>7} {'C':>4} {'findings':28} {'Fd':>4} {'Dr':>4} {'pass':>4}"
            f"  {'shape fit/true':27} sindy")
    lines = [head]
    for r in rows:
        sp = r["spec"]
        drops = ",".join(str(c) for _, c in r.get("dropped", [])) or "-"
        if "error" in r:
            lines.append(f"{r['case']:>4} {r['family'][:22]:22} {sp['noise_gray']:>3.1f} {_ab(sp):>3} {drops:>11}  "
                         f"analyze failed: {r['error']}")
            continue
        c = r["criteria"]
        g = r["gaps"]
        gfc = "/".join(str(sum(x["outcome"] in o for x in g))
                       for o in (("found",), ("counted",), ("clean",), ("lost", "miscounted"))) if g else "-"
        rec = f"{r['recalled']}/{r['measurable']}"
        cor = "n/a" if r["cor_error_mean"] is None else f"{1000 * r['cor_error_mean']:.2f}"
        found = ",".join(f.replace("_restitution", "_rest").replace("unexplained", "unexpl") for f in r["found"]) \
            or "none"
        sindy = r.get("sindy", {})
        sfound = ",".join(sindy.get("found", [])) or ("error" if "error" in sindy else ("none" if sindy else "n/a"))
        lines.append(f"{r['case']:>4} {r['family'][:22]:22} {sp['noise_gray']:>3.1f} {_ab(sp):>3} {drops:>11} "
                     f"{rec:>11} "
                     f"{_mark(c['recall']):>4} {len(r['invented_t']):>3} {_mark(c['invented']):>4} {gfc:>12} "
                     f"{_mark(c['gaps'] if g else None):>4} {cor:>7} {_mark(c['cor']):>4} {found[:28]:28} "
                     f"{_mark(c['findings']):>4} {_mark(c['improved']):>4} {_mark(r['pass']):>4}  "
                     f"{_shape_text(r):27} {sfound}")
    n_pass = sum(bool(r.get("pass")) for r in rows)
    lines.append(f"{n_pass}/{len(rows)} cases pass (nz: read noise, gray levels; a/b: accelerometers, blur; "
                 "drops: lengths of the runs of lost frames; "
                 f"R recall >= {100 * HARDER_GOALS['recall']:.0f} %, I no invented "
                 f"impact, G every gap's impact found (F) or counted (C), a gap in a flight clean (K), none lost (L), "
                 f"C mean |COR error| <= {HARDER_GOALS['cor_error_mean']}, "
                 "Fd findings vs truth, Dr D_r lowered by every correct catalogue finding, out of the catalogue: "
                 "D lowered by the unexplained finding's shape model; shape fit/true: its weight fraction wf and "
                 "decay L (mm), or the lower plate's two CORs, fitted/true)")
    return "\n".join(lines)


def prove_harder(seed: int = 0, out: str | Path | None = None, frames: int = 1000, cases: int | None = None,
                 sindy: bool = True, progress: bool = False) -> dict:
    """Run the harder set; returns {"settings", "goals", "rows", "table"}; writes proof.json into ``out``."""
    import sys
    import tempfile

    from tqdm import tqdm

    if frames < 200:
        raise RecordingError(f"--frames must be >= 200 (enough flights to fit), got {frames}")
    if cases is not None and cases < 1:
        raise RecordingError(f"--cases must be >= 1, got {cases}")
    work = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="vibro_prove_harder_"))
    work.mkdir(parents=True, exist_ok=True)
    specs = draw_harder(seed, frames, cases)
    rows = [run_harder_case(s, work, sindy)
            for s in tqdm(specs, desc="prove --harder", unit="case", disable=not progress, file=sys.stderr)]
    table = format_harder_table(rows)
    result = {"settings": {"harder": True, "cases": len(specs), "seed": seed, "frames": frames, "work_dir": str(work)},
              "goals": HARDER_GOALS, "criteria": list(CRITERIA), "rows": rows, "table": table.splitlines(),
              "passed": sum(bool(r.get("pass")) for r in rows)}
    (work / "proof.json").write_text(json.dumps(result, indent=1, default=float), encoding="utf-8")
    return result
