"""Benchmark vibro_sim: COR model, Hertz model, synthetic recording; Hertz effective COR.

Run: scripts/py bench/bench_sim.py [--quick] [--regime]
Prints tables and writes bench/results/sim.json. Baselines are measured in the same run:
  * COR model vs a fine-step ODE of the same system (DOP853, max_step 20 us, event location);
  * Hertz model vs the COR model;
  * synthesis: frames/s, and the Fourier sub-pixel renderer vs a naive integer-shift render;
  * a frame's read noise: vibro_sim.synth.sensor_noise.read_noise vs NumPy's Generator.normal (rounds interleaved).
Goals: COR 1.5 s <= 50 ms, Hertz 1.5 s <= 2 s, 1500-frame synthesis <= 30 s.
--regime also rescans the shaker acceleration for the synth default (two impacts per cycle).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from vibro_model.kinematics import StructureKinematics
from vibro_sim.cor_model import simulate_cor
from vibro_sim.hertz_model import hertz_effective_cor, simulate_hertz, undamped_max_penetration
from vibro_sim.params import BallCavity
from vibro_sim.restitution import PerPlate, Scattered
from vibro_sim.synth import SynthConfig, synthesize
from vibro_sim.synth.render import Renderer, choose_layout
from vibro_sim.synth.scenario import EFFECTS, build_models
from vibro_sim.synth.trajectory import regime, simulate_window

OUT = Path(__file__).resolve().parent / "results" / "sim.json"
F_HZ = 22.0
S = StructureKinematics(27.0 / (2 * math.pi * F_HZ) ** 2, F_HZ, phase_rad=0.4)
CAV = BallCavity()
LAW = Scattered(PerPlate(0.6, 0.75), 0.04, seed=1)


def timed(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def fine_step_ode(t_end=1.5):
    b, g = CAV.free_play_m, CAV.g_eff_mps2
    t, y, v, k = 0.0, 0.0, 0.0, 0
    n_imp = 0
    while t < t_end:
        def top(tt, s):
            return b - (s[0] - S.position(tt))

        def bot(tt, s):
            return s[0] - S.position(tt) + b
        top.terminal = bot.terminal = True
        top.direction = bot.direction = -1
        sol = solve_ivp(lambda tt, s: (s[1], -g), (t, t_end), (y, v), method="DOP853", rtol=1e-12,
                        atol=1e-15, max_step=2e-5, events=(top, bot))
        hits = [(te[0], p) for te, p in zip(sol.t_events, ("top", "bottom")) if len(te)]
        if not hits:
            break
        te, plate = min(hits)
        i = 0 if plate == "top" else 1
        yb, vb = sol.y_events[i][0]
        vs = S.velocity(te)
        e = LAW.cor(plate, vb - vs, k)
        t = te + 1e-9
        y = S.position(te) + (b if plate == "top" else -b)
        v = vs - e * (vb - vs)
        k += 1
        n_imp += 1
    return n_imp


def bench_models(quick):
    rows = {}
    t_cor, r = timed(lambda: simulate_cor(S, CAV, LAW, None, t_end_s=1.5), 3 if quick else 7)
    t_ode, n_ode = timed(fine_step_ode, 1)
    rows["cor_model_1p5s"] = {"seconds": t_cor, "impacts": len(r.impacts), "goal_s": 0.05,
                              "baseline": "fine-step DOP853 ODE with events", "baseline_s": t_ode,
                              "baseline_impacts": n_ode, "speedup_vs_baseline": t_ode / t_cor}
    t_h, h = timed(lambda: simulate_hertz(S, CAV, LAW, None, t_end_s=1.5), 1 if quick else 3)
    rows["hertz_model_1p5s"] = {"seconds": t_h, "impacts": len(h.impacts), "goal_s": 2.0,
                                "baseline": "COR model (same run)", "baseline_s": t_cor,
                                "ratio_to_baseline": t_h / t_cor}
    return rows


def naive_integer_render(layout, n, traj):
    """Baseline renderer: integer np.roll of precomputed layers (no sub-pixel motion)."""
    rng = np.random.default_rng(0)
    H, W = layout.height_px, layout.width_px
    plate = rng.random((H, W)) * 200
    ball = rng.random((H, W)) * 200
    for k in range(n):
        s = int(round(-traj.structure_m[k] * 1e3 / layout.mm_per_px))
        bb = int(round(-traj.ball_m[k] * 1e3 / layout.mm_per_px))
        img = np.roll(plate, s, axis=0) * 0.5 + np.roll(ball, bb, axis=0) * 0.5
        img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    return img


def bench_synth(quick):
    frames = 300 if quick else 1500
    tmp = Path(tempfile.mkdtemp(prefix="bench_sim_"))
    try:
        cfg = SynthConfig(frames=frames, seed=1)
        t = time.perf_counter()
        truth = synthesize(tmp / "rec", cfg, progress=False)
        t_all = time.perf_counter() - t
        # render-only comparison on the same trajectory
        models = build_models(cfg, 0.4)
        traj = simulate_window(cfg, models)
        layout = choose_layout(160, 480, cfg.ball_diameter_mm, cfg.gap_mm, models.structure.bound(0) * 1e3,
                               None, 31)
        rend = Renderer(layout, np.random.default_rng(0))
        n = min(frames, 300)
        t = time.perf_counter()
        for k in range(n):
            rend.render(traj.structure_m[k] * 1e3, traj.ball_m[k] * 1e3)
        t_fourier = (time.perf_counter() - t) / n
        t = time.perf_counter()
        naive_integer_render(layout, n, traj)
        t_naive = (time.perf_counter() - t) / n
        size = sum(p.stat().st_size for p in (tmp / "rec").rglob("*") if p.is_file())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"synth_recording": {"frames": frames, "seconds": t_all, "frames_per_s": frames / t_all,
                                "goal_s_for_1500": 30.0, "impacts": len(truth["impacts"]),
                                "bytes": size,
                                "render_ms_per_frame_fourier": 1e3 * t_fourier,
                                "render_ms_per_frame_naive_integer_shift": 1e3 * t_naive,
                                "fourier_vs_naive_ratio": t_fourier / t_naive}}


def bench_noise(quick):
    """ms per frame (160 x 480) of the synthetic camera's read noise, :func:`read_noise` against NumPy's
    ``Generator.normal`` (what synthesis drew before), rounds of each interleaved, medians of CPU time."""
    from vibro_sim.synth.sensor_noise import read_noise

    rng = np.random.default_rng(0)
    shape, n, rounds = (480, 160), 200 if quick else 1000, 5
    ways = {"numpy_normal": lambda: rng.normal(0.0, 2.0, shape), "table": lambda: read_noise(rng, shape, 2.0)}
    times: dict[str, list[float]] = {k: [] for k in ways}
    for _ in range(rounds):
        for name, draw in ways.items():
            t = time.process_time()
            for _ in range(n):
                draw()
            times[name].append((time.process_time() - t) / n * 1e3)
    med = {k: statistics.median(v) for k, v in times.items()}
    return {"read_noise_ms_per_frame": {"table": med["table"], "numpy_normal": med["numpy_normal"],
                                        "table_vs_numpy_ratio": med["table"] / med["numpy_normal"],
                                        "frames_per_round": n, "rounds": rounds}}


def bench_hertz_cor():
    speeds = (0.1, 0.2, 0.5, 1.0, 2.0)
    targets = (0.5, 0.6, 0.75, 0.9)
    per_impact = hertz_effective_cor(CAV, targets, speeds)
    fixed = hertz_effective_cor(CAV, targets, speeds, delta_a=undamped_max_penetration(CAV, 0.5))
    return {"per_impact_delta_a": per_impact, "fixed_delta_a_at_0p5ms": fixed}


def bench_replay():
    """D (Eq. 18) of the replayed models against a COR-model 'measurement' with scattered
    CORs and per-flight forces, replayed from t = 1.4 s to 2.5 s."""
    from vibro_sim.forces import PerFlight
    from vibro_sim.replay import ReplayInputs, compare_models

    forces = PerFlight(list(np.random.default_rng(2).normal(0.0, 1e-4, 200)))
    w = simulate_cor(S, CAV, LAW, forces, y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=2.5)
    t0 = 1.4
    inputs = ReplayInputs(structure=S, impact_times_s=[i.t_s for i in w.impacts],
                          impact_plates=[i.plate for i in w.impacts],
                          impact_cors=[i.cor for i in w.impacts],
                          flight_forces_n=[forces.constant_n(k) for k in range(len(w.impacts) + 1)],
                          t_start_s=t0, y_rel_m=float(w.relative_position(t0)),
                          v_rel_mps=float(w.velocity(t0) - S.velocity(t0)), t_end_s=2.5)
    t = np.linspace(t0, 2.5, 1101)
    out = {}
    for mode in ("impact", "calibrated"):
        sc = compare_models(inputs, CAV, t, w.sample(t), hertz_delta_a=mode)
        out[f"hertz_delta_a_{mode}"] = sc["hertz_model"]["deviation"]
    out["cor_model"] = sc["cor_model"]["deviation"]
    return out


def bench_regime():
    out = {}
    effects = [{}] + [{name: {}} for name in EFFECTS]
    for acc in (20, 24, 27, 30, 33, 36, 40):
        ok = []
        for eff in effects:
            good = 0
            for seed in range(4):
                cfg = SynthConfig(effects=eff, accel_mps2=acc, seed=seed, frames=1500)
                ph = float(np.random.default_rng(seed).uniform(0, 2 * math.pi))
                r = regime(simulate_window(cfg, build_models(cfg, ph)), F_HZ)
                good += int(r["alternating"] and abs(r["impacts_per_cycle"] - 2) < 0.05)
            ok.append(good)
        out[str(acc)] = dict(zip(["baseline"] + list(EFFECTS), ok))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats, 300-frame synthesis")
    ap.add_argument("--regime", action="store_true", help="rescan the default shaker acceleration")
    args = ap.parse_args(argv)
    res = {"models": bench_models(args.quick)}
    res.update(bench_synth(args.quick))
    res.update(bench_noise(args.quick))
    res["hertz_effective_cor"] = bench_hertz_cor()
    res["replay_deviation"] = bench_replay()
    if args.regime:
        res["regime_scan_ok_of_4_seeds"] = bench_regime()

    print(f"{'benchmark':28s} {'seconds':>9s} {'goal':>7s} {'baseline':>9s} {'ratio':>8s}")
    m = res["models"]
    c, h, s = m["cor_model_1p5s"], m["hertz_model_1p5s"], res["synth_recording"]
    print(f"{'COR model 1.5 s':28s} {c['seconds']:9.4f} {c['goal_s']:7.3f} {c['baseline_s']:9.3f} "
          f"{c['speedup_vs_baseline']:7.1f}x  (fine-step ODE / COR)")
    print(f"{'Hertz model 1.5 s':28s} {h['seconds']:9.4f} {h['goal_s']:7.3f} {h['baseline_s']:9.4f} "
          f"{h['ratio_to_baseline']:7.1f}x  (Hertz / COR)")
    print(f"{'synth ' + str(s['frames']) + ' frames':28s} {s['seconds']:9.2f} {30.0:7.1f} "
          f"{'':9s} {s['frames_per_s']:6.0f} frames/s")
    print(f"{'render per frame (ms)':28s} {s['render_ms_per_frame_fourier']:9.3f} {'':7s} "
          f"{s['render_ms_per_frame_naive_integer_shift']:9.3f} {s['fourier_vs_naive_ratio']:7.1f}x  (Fourier / naive)")
    nz = res["read_noise_ms_per_frame"]
    print(f"{'read noise per frame (ms)':28s} {nz['table']:9.3f} {'':7s} {nz['numpy_normal']:9.3f} "
          f"{nz['table_vs_numpy_ratio']:7.2f}x  (table / Generator.normal)")
    print("\nHertz effective COR (delta_a = undamped max penetration at each impact's speed):")
    print(f"{'target':>7s} " + " ".join(f"{v:>8.2f}" for v in (0.1, 0.2, 0.5, 1.0, 2.0)) + "   m/s")
    for mode in ("per_impact_delta_a", "fixed_delta_a_at_0p5ms"):
        if mode != "per_impact_delta_a":
            print("delta_a fixed at the undamped max penetration of a 0.5 m/s impact:")
        rows = res["hertz_effective_cor"][mode]
        for e in sorted({r["target_cor"] for r in rows}):
            vals = [r["effective_cor"] for r in rows if r["target_cor"] == e]
            print(f"{e:7.2f} " + " ".join(f"{x:8.4f}" for x in vals))
    rd = res["replay_deviation"]
    print("\nreplay of a COR-model 'measurement' (1.1 s), D of Eq. 18:")
    print(f"  COR model {rd['cor_model']:.2e}   Hertz (delta_a = delta_max) {rd['hertz_delta_a_impact']:.4f}   "
          f"Hertz (calibrated delta_a) {rd['hertz_delta_a_calibrated']:.4f}")
    if args.regime:
        print("\nregime scan (seeds of 4 with two alternating impacts per cycle):")
        for acc, row in res["regime_scan_ok_of_4_seeds"].items():
            print(f"  {acc:>3s} m/s^2: {row}")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(res, indent=1))
    print(f"\nwrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
