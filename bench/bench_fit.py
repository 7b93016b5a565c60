"""Accuracy of the identification (vibro_fit) on exact synthetic motion, against the truth.

Scenarios (1500 frames at 1000 fps, 22 Hz, A = 3 mm, paper ball and gap, 3 seeds each):
- ``per_flight_friction``: vibro_sim exact COR model, per-plate COR 0.6 / 0.75 with 0.03 scatter,
  a random constant force per flight (uniform +-8 % of the weight);
- ``direction_friction``: vibro_fit.synthetic, constant friction per direction (-5 % g up, +3 % g down).
Noise: white, 0.0005 mm (~0.01 px at 0.05 mm/px, DIC at sigma = 2 gray levels) and 10x that.
Methods: ``paper`` (Eq. 15-16), ``joint`` (plate constraint + friction shrinkage) and the baseline
``finite_diff`` (central differences around each impact), all in the same run.

Then end to end through DIC: a rendered speckle recording of an exact motion (vibro_dic.speckle) and
vibro_sim.synth recordings (baseline, asymmetric COR, Coulomb friction, quadratic drag, asymmetric COR
with 0.5 ms motion blur), scored against their truth files.

Run: scripts/py bench/bench_fit.py  -> table + bench/results/fit.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from vibro_fit.identify import identify  # noqa: E402
from vibro_fit.impacts import finite_difference_cor  # noqa: E402
from vibro_fit.synthetic import paper_rig, sample_track, simulate  # noqa: E402
from vibro_io.dictrack import DicTrack  # noqa: E402

M_KG, G, FPS, N = 1.82e-4, 9.81, 1000.0, 1500
NOISES = (0.0005, 0.005)
SEEDS = (1, 2, 3)


def scenario_per_flight(seed: int, noise: float):
    from vibro_model.kinematics import StructureKinematics
    from vibro_sim.cor_model import simulate_cor
    from vibro_sim.forces import PerFlight
    from vibro_sim.params import BallCavity
    from vibro_sim.restitution import PerPlate, Scattered

    rng = np.random.default_rng(100 + seed)
    forces = tuple(M_KG * G * rng.uniform(-0.08, 0.08, 400))
    S = StructureKinematics(3e-3, 22.0, 0.3, 0.0)
    res = simulate_cor(S, BallCavity(), Scattered(PerPlate(top=0.6, bottom=0.75), 0.03, seed=seed),
                       PerFlight(forces), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=N / FPS + 0.01)
    t = np.arange(N) / FPS
    r = np.random.default_rng(seed)
    ball = 1e3 * (res.sample(t) - res.sample(0.0)) + noise * r.standard_normal(N)
    st = 1e3 * (S.position(t) - S.position(0.0)) + noise * r.standard_normal(N)
    track = DicTrack(frame=np.arange(N), t_s=t, ball_mm=ball, structure_mm=st, ball_valid=np.full(N, 20),
                     structure_valid=np.full(N, 40), ball_zncc=np.full(N, 0.99),
                     structure_zncc=np.full(N, 0.99), lost=np.zeros(N, bool))
    imps = [(i.t_s, i.cor) for i in res.impacts]
    flights = [(f.t_start_s, f.t_end_s, f.mean_force_n) for f in res.flights]
    return track, imps, flights


def scenario_direction(seed: int, noise: float):
    truth = simulate(amplitude_m=3e-3, force_up_n=-0.05 * M_KG * G, force_down_n=0.03 * M_KG * G,
                     cor_jitter=0.03, duration_s=N / FPS + 0.05, seed=seed)
    track = sample_track(truth, noise_mm=noise, n_frames=N, seed=seed)
    imps = [(i.t_s, i.cor) for i in truth.impacts]
    starts = [p[0] for p in truth.pieces] + [1e9]
    flights = [(starts[k], starts[k + 1], M_KG * (truth.flight_accel_mps2[k] + G)) for k in range(len(truth.pieces))]
    return track, imps, flights


def evaluate(track, imps, flights, method):
    rig = paper_rig()
    t0 = time.perf_counter()
    ident = identify(track, rig, method=method)
    elapsed = time.perf_counter() - t0
    tt = np.array([t for t, _ in imps])
    cor_err, t_err, fd_err, z = [], [], [], []
    for e in ident.impacts:
        k = int(np.argmin(abs(tt - e.t_s)))
        cor_err.append(abs(e.cor - imps[k][1]))
        z.append((e.cor - imps[k][1]) / e.cor_std)
        t_err.append(abs(e.t_s - imps[k][0]))
        fd = finite_difference_cor(track.t_s, track.ball_mm, track.structure_mm, e.t_s)
        if fd is not None:
            fd_err.append(abs(fd - imps[k][1]))
    f_err = []
    for fl in ident.flights:
        if not fl.is_free or fl.t_start_s < 0.002:
            continue
        mid = 0.5 * (fl.t_start_s + fl.t_end_s)
        tf = [f for f in flights if f[0] < mid < f[1]]
        if tf:
            f_err.append(abs(fl.friction_n(M_KG, G)[0] - tf[0][2]) / (M_KG * G))
    s = ident.structure
    return {
        "n_impacts": len(ident.impacts), "cor_mae": float(np.mean(cor_err)), "cor_max": float(np.max(cor_err)),
        "t_mae_ms": 1e3 * float(np.mean(t_err)), "t_max_ms": 1e3 * float(np.max(t_err)),
        "fd_cor_mae": float(np.mean(fd_err)),
        "cor_z_rms": float(np.sqrt(np.mean(np.square(z)))),  # ~1 when cor_std is calibrated
        "friction_mean_pct_weight": 100 * float(np.mean(f_err)), "friction_max_pct_weight": 100 * float(np.max(f_err)),
        "amplitude_err_pct": 100 * abs(s.amplitude_mm - 3.0) / 3.0, "frequency_err_hz": abs(s.frequency_hz - 22.0),
        "identify_s": elapsed, "regime": ident.regime.name,
    }


def end_to_end(n: int = N, mm_per_px: float = 0.05) -> dict:
    """Rendered speckle recording (vibro_dic.speckle, sigma = 2 gray levels, no blur) of an exact motion
    -> vibro analyze (DIC icgn + identification) -> errors against the truth, fitted vs finite differences."""
    import tempfile

    from vibro_app.analyze import FitPlan, analyze_recording
    from vibro_dic.speckle import RigScene, write_scene_recording
    from vibro_fit.validation import compare_to_truth
    from vibro_io.dictrack import read_dic_csv

    truth = simulate(amplitude_m=3e-3, duration_s=n / FPS + 0.05, cor_jitter=0.03, seed=5,
                     force_up_n=-0.04 * M_KG * G, force_down_n=0.02 * M_KG * G)
    t = np.arange(n) / FPS
    ball, st = 1e3 * truth.ball_m(t), 1e3 * truth.structure_m(t)
    rows = int(20 / mm_per_px) + 100
    scene = RigScene(shape=(rows, 200), split_col=100, ball_x_px=150, ball_y0_px=rows / 2, ball_radius_px=40)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_scene_recording(f"{tmp}/rec", scene, (ball - ball[0]) / mm_per_px, (st - st[0]) / mm_per_px,
                              noise_sigma=2.0, mm_per_px=mm_per_px)
        out["render_s"] = time.perf_counter() - t0
        for method in ("paper", "joint"):
            t0 = time.perf_counter()
            doc = analyze_recording(f"{tmp}/rec", f"{tmp}/out_{method}", progress=False, report=False,
                                    fit=FitPlan(method=method))
            el = time.perf_counter() - t0
            tdoc = {"effects": [], "structure": {"amplitude_mm": 3.0, "frequency_hz": 22.0},
                    "impacts": [{"t": i.t_s, "plate": i.plate, "cor": i.cor} for i in truth.impacts]}
            cmp = compare_to_truth(doc, tdoc, M_KG)
            track = read_dic_csv(f"{tmp}/out_{method}/dic.csv")
            tt = np.array([i.t_s for i in truth.impacts])
            fd = [abs(finite_difference_cor(track.t_s, track.ball_mm, track.structure_mm, i["t"])
                      - truth.impacts[int(np.argmin(abs(tt - i["t"])))].cor) for i in doc["impacts"]]
            fe = []
            for f in doc["flights"]:
                if f["friction_n"] is not None and f["t_start"] > 0.002:
                    expect = (-0.04 if f["direction"] == "up" else 0.02) * M_KG * G
                    fe.append(100 * abs(f["friction_n"] - expect) / (M_KG * G))
            cmp.update(fd_cor_mae=float(np.mean(fd)), fd_over_fit=float(np.mean(fd)) / cmp["cor_mae"],
                       friction_mean_pct_weight=float(np.mean(fe)), friction_max_pct_weight=float(np.max(fe)),
                       dic_noise_mm=doc["identification"]["noise_mm"], analyze_s=el,
                       cor_model_deviation=doc["simulation"]["cor_model"]["deviation"])
            out[method] = cmp
            print(f"end-to-end {n} frames, {mm_per_px} mm/px, {method}: COR MAE {cmp['cor_mae']:.2e} "
                  f"(max {cmp['cor_max']:.2e}), FD {cmp['fd_cor_mae']:.4f} ({cmp['fd_over_fit']:.0f}x), "
                  f"t max {cmp['t_max_ms']:.5f} ms, F max {cmp['friction_max_pct_weight']:.2f} % mg, "
                  f"A {cmp['amplitude_err_pct']:.4f} %, f {cmp['frequency_err_hz']:.1e} Hz, "
                  f"track noise {cmp['dic_noise_mm']:.5f} mm, {el:.1f} s")
    return out


SYNTH_SCENARIOS = {   # name: SynthConfig options
    "synth_baseline": {},
    "synth_asymmetric": {"effects": {"asymmetric_restitution": {}}},
    "synth_coulomb": {"effects": {"coulomb_friction": {}}},
    "synth_quadratic_drag": {"effects": {"quadratic_drag": {}}},
    "synth_asym_blur": {"effects": {"asymmetric_restitution": {}}, "blur": True},
}


def synth_recordings() -> list[dict]:
    """vibro_sim.synth recordings (1500 frames, sigma = 2 gray levels, no blur, accelerometers with a 4 ms
    clock offset) -> vibro analyze (DIC + identification + replay) -> errors against the truth file."""
    import tempfile

    from vibro_app.analyze import FitPlan, analyze_recording
    from vibro_fit.validation import compare_to_truth
    from vibro_io.dictrack import read_dic_csv
    from vibro_sim.synth import SynthConfig, synthesize

    rows = []
    for name, opts in SYNTH_SCENARIOS.items():
        with tempfile.TemporaryDirectory() as tmp:
            truth = synthesize(f"{tmp}/rec", SynthConfig(frames=N, seed=7, clock_offset_s=0.004, **opts),
                               progress=False)
            tt = np.array([i["t"] for i in truth["impacts"]])
            for method in ("paper", "joint"):
                t0 = time.perf_counter()
                doc = analyze_recording(f"{tmp}/rec", f"{tmp}/out_{method}", progress=False, report=False,
                                        fit=FitPlan(method=method))
                el = time.perf_counter() - t0
                cmp = compare_to_truth(doc, truth, M_KG)
                track = read_dic_csv(f"{tmp}/out_{method}/dic.csv")
                fd = []
                for i in doc["impacts"]:
                    e = finite_difference_cor(track.t_s, track.ball_mm, track.structure_mm, i["t"])
                    if e is not None:
                        fd.append(abs(e - truth["impacts"][int(np.argmin(abs(tt - i["t"])))]["cor"]))
                cmp.update(scenario=name, method=method, fd_cor_mae=float(np.mean(fd)),
                           fd_over_fit=float(np.mean(fd)) / cmp["cor_mae"], analyze_s=el,
                           clock_offset_err_ms=1e3 * abs(doc["accelerometers"]["clock_offset_s"]
                                                         - truth["clock_offset_s"]),
                           cor_model_D=doc["simulation"]["cor_model"]["deviation"],
                           hertz_model_D=doc["simulation"]["hertz_model"]["deviation"],
                           regime=doc["regime"]["name"], track_noise_mm=doc["identification"]["noise_mm"])
                rows.append(cmp)
                fmt = lambda v, spec: "n/a" if v is None else format(v, spec)  # noqa: E731
                print(f"{name:<21} {method:<6} {cmp['n_matched']:>3}/{cmp['n_truth']:<3} COR MAE {cmp['cor_mae']:.2e} "
                      f"(max {cmp['cor_max']:.2e}) FD {cmp['fd_cor_mae']:.4f} ({cmp['fd_over_fit']:.0f}x) "
                      f"t max {cmp['t_max_ms']:.5f} ms  F max {fmt(cmp.get('friction_max_pct_weight'), '.2f')} % mg  "
                      f"A {cmp['amplitude_err_pct']:.4f} %  f {cmp['frequency_err_hz']:.1e} Hz  "
                      f"clock {cmp['clock_offset_err_ms']:.4f} ms  D cor {fmt(cmp['cor_model_D'], '.4f')} "
                      f"hertz {fmt(cmp['hertz_model_D'], '.4f')}  {el:.1f} s")
    return rows


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=__doc__.strip().splitlines()[0],
                            epilog="Writes bench/results/fit.json; no options.").parse_args(argv)
    results = []
    print(f"{'scenario':<20} {'noise mm':>8} {'method':<6} {'COR MAE':>9} {'COR max':>9} {'FD MAE':>8} "
          f"{'FD/fit':>7} {'t MAE ms':>9} {'t max ms':>9} {'F mean%':>8} {'F max%':>7} {'A err%':>7} "
          f"{'f err Hz':>9} {'z rms':>6} {'time s':>6}")
    for name, make in (("per_flight_friction", scenario_per_flight), ("direction_friction", scenario_direction)):
        for noise in NOISES:
            data = [make(seed, noise) for seed in SEEDS]
            for method in ("paper", "joint"):
                runs = [evaluate(*d, method) for d in data]
                agg = {k: float(np.mean([r[k] for r in runs])) for k in runs[0] if k != "regime"}
                for k in ("cor_max", "t_max_ms", "friction_max_pct_weight", "amplitude_err_pct", "frequency_err_hz"):
                    agg[k] = float(np.max([r[k] for r in runs]))
                agg["fd_over_fit"] = agg["fd_cor_mae"] / agg["cor_mae"]
                agg["regimes"] = sorted({r["regime"] for r in runs})
                row = {"scenario": name, "noise_mm": noise, "method": method, "seeds": list(SEEDS), **agg}
                results.append(row)
                print(f"{name:<20} {noise:>8.4f} {method:<6} {agg['cor_mae']:>9.2e} {agg['cor_max']:>9.2e} "
                      f"{agg['fd_cor_mae']:>8.4f} {agg['fd_over_fit']:>7.0f} {agg['t_mae_ms']:>9.5f} "
                      f"{agg['t_max_ms']:>9.5f} {agg['friction_mean_pct_weight']:>8.3f} "
                      f"{agg['friction_max_pct_weight']:>7.2f} {agg['amplitude_err_pct']:>7.4f} "
                      f"{agg['frequency_err_hz']:>9.2e} {agg['cor_z_rms']:>6.2f} {agg['identify_s']:>6.2f}")
    for name in ("per_flight_friction", "direction_friction"):
        for noise in NOISES:
            p = next(r for r in results if r["scenario"] == name and r["noise_mm"] == noise and r["method"] == "paper")
            j = next(r for r in results if r["scenario"] == name and r["noise_mm"] == noise and r["method"] == "joint")
            print(f"joint vs paper, {name}, noise {noise}: COR MAE ratio paper/joint = "
                  f"{p['cor_mae'] / j['cor_mae']:.2f}")
    # DIC-quality weighting: valid mesh points drawn in 2..20 per frame, noise std 0.005 mm x sqrt(16/valid)
    wres = {}
    for seed in SEEDS:
        truth = simulate(amplitude_m=3e-3, duration_s=N / FPS + 0.05, cor_jitter=0.03, seed=seed)
        track = sample_track(truth, n_frames=N, noise_mm=0.0, seed=seed)
        rng = np.random.default_rng(seed)
        valid = rng.integers(2, 21, N)
        track.ball_valid = valid
        track.ball_mm = track.ball_mm + 0.005 * np.sqrt(16 / valid) * rng.standard_normal(N)
        tt = np.array([i.t_s for i in truth.impacts])
        for w in ("none", "dic_valid"):
            ident = identify(track, paper_rig(), weights=w)
            wres.setdefault(w, []).extend(abs(i.cor - truth.impacts[int(np.argmin(abs(tt - i.t_s)))].cor)
                                          for i in ident.impacts)
    weighting = {w: float(np.mean(v)) for w, v in wres.items()}
    weighting["ratio_none_over_dic_valid"] = weighting["none"] / weighting["dic_valid"]
    print(f"DIC-quality weighting (uneven valid counts): COR MAE none {weighting['none']:.2e}, "
          f"dic_valid {weighting['dic_valid']:.2e}, ratio {weighting['ratio_none_over_dic_valid']:.2f}")
    e2e = end_to_end()
    synth = synth_recordings()
    targets = {"cor_mae": 0.005, "t_max_ms": 0.1, "friction_max_pct_weight": 2.0, "amplitude_err_pct": 0.5,
               "frequency_err_hz": 0.01, "fd_over_fit_min": 5.0}
    out = {"description": __doc__.strip().splitlines()[0], "targets": targets, "frames": N, "fps": FPS,
           "results": results, "weighting": weighting, "end_to_end": e2e, "synth": synth}
    path = ROOT / "bench" / "results" / "fit.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"written {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
