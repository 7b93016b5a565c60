"""What tracking across skipped frames costs: the live tracker's per-frame DIC cost when it tracks every frame,
every 2nd, 3rd or 7th, or jumps over stalls, against tracking the next frame, all in one run.

Run: scripts/py bench/bench_gap_cost.py [--frames 600] [--repeats 3] [--seed 3]
Prints a table and writes bench/results/gap_cost.json.

A live tracker that has fallen behind jumps to the newest image (vibro_dic.catch_up) and tracks it from the motion
prediction across the gap. That pays only if a frame after a gap costs about what the next frame costs: if it
costs more, every catch-up makes the tracker fall further behind. Here one synthetic recording's images (decoded
once, in memory) are tracked by ``DicTracker.for_rig`` (the texture check's usable subsets, as the live node builds
it) in these schedules:

- ``every frame``: frames 0, 1, 2, ... (the baseline);
- ``every 2nd`` / ``3rd`` / ``7th``: frames 0, k, 2k, ... (a tracker at 1/k of the camera's rate);
- ``stalls``: every frame, but 20 frames skipped after every 100 tracked (a stall, then the jump to the newest).

Per schedule: CPU ms per tracked frame (time.process_time of this process, best of the repeats; BLAS/OpenCV on
one thread), its ratio to the baseline, the share of tracked frames that took the prediction path (no integer
search: IC-GN straight from the predicted displacement), searches widened beyond the window and whole-image
searches per 100 frames, frames lost, and the ball's error against the synth's truth (RMS px, rows).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

cv2.setNumThreads(1)
REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "results" / "gap_cost.json"


def schedules(n: int) -> dict[str, list[int]]:
    """Frame indices each schedule tracks (frame 0, the reference, always first)."""
    stalls, k = [], 0
    while k < n:
        stalls.extend(range(k, min(k + 100, n)))
        k += 120
    return {"every frame": list(range(n)), "every 2nd": list(range(0, n, 2)), "every 3rd": list(range(0, n, 3)),
            "every 7th": list(range(0, n, 7)), "stalls (20 skipped per 100)": stalls}


def one_pass(rec: Path, images: list[np.ndarray], frames: list[int], truth_px: np.ndarray) -> dict:
    """Track ``frames`` of ``images``; CPU seconds per tracked frame (frame 0 excluded), path counters, losses,
    the ball's error (px)."""
    from vibro_dic.tracker import DicTracker, reference_texture
    from vibro_io.recording import open_recording

    recording = open_recording(rec)
    tracker = DicTracker.for_rig(images[0], recording.rig)
    tracker.use_texture(reference_texture(recording))
    fps = recording.rig.camera.fps
    tracker.track_image(0, 0.0, images[0])
    err, lost = [], 0
    t0 = time.process_time()
    for k in frames[1:]:
        ft = tracker.track_image(k, k / fps, images[k])
        lost += int(ft.lost)
        err.append(ft.ball_mm / recording.rig.camera.mm_per_px - truth_px[k])
    cpu = time.process_time() - t0
    n = len(frames) - 1
    meshes = (tracker.ball, tracker.structure)
    err = np.asarray(err)
    ok = np.isfinite(err)
    return {"tracked": n, "cpu_ms_per_frame": 1e3 * cpu / n,
            "predicted_share": sum(getattr(m, "n_predicted", 0) for m in meshes) / (2 * n),
            "widened_per_100": 100 * sum(getattr(m, "n_widened", 0) for m in meshes) / n,
            "global_per_100": 100 * sum(getattr(m, "n_global", 0) for m in meshes) / n,
            "by_body": {m.name: {"predicted": getattr(m, "n_predicted", 0), "widened": getattr(m, "n_widened", 0),
                                 "global": getattr(m, "n_global", 0)} for m in meshes},
            "lost": lost, "ball_error_rms_px": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else math.nan}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=600, help="frames of the synthetic recording (default 600)")
    ap.add_argument("--repeats", type=int, default=3, help="passes per schedule, the fastest kept (default 3)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    if args.frames < 50 or args.repeats < 1:
        ap.error("--frames must be >= 50 and --repeats >= 1")
    from vibro_io.frames import read_image
    from vibro_sim.synth import SynthConfig, synthesize

    base = Path(tempfile.mkdtemp(prefix="bench_gap_cost_"))
    try:
        rec = base / "rec"
        truth = synthesize(rec, SynthConfig(frames=args.frames, accel=False, seed=args.seed), progress=False)
        ball_mm = np.asarray(truth["frames"]["ball_mm"], float)
        truth_px = (ball_mm - ball_mm[0]) / truth["image"]["mm_per_px"]
        images = [read_image(p).astype(np.float32) for p in sorted((rec / "frames").iterdir())[:args.frames]]
        rows = {}
        for name, frames in schedules(len(images)).items():
            passes = [one_pass(rec, images, frames, truth_px) for _ in range(args.repeats)]
            rows[name] = min(passes, key=lambda r: r["cpu_ms_per_frame"])
    finally:
        shutil.rmtree(base, ignore_errors=True)
    baseline = rows["every frame"]["cpu_ms_per_frame"]
    print(f"{'schedule':30s} {'tracked':>7s} {'ms/frame':>9s} {'ratio':>6s} {'predicted':>9s} {'widened':>8s} "
          f"{'global':>7s} {'lost':>5s} {'ball err px':>11s}")
    for name, r in rows.items():
        r["ratio_to_every_frame"] = r["cpu_ms_per_frame"] / baseline
        print(f"{name:30s} {r['tracked']:7d} {r['cpu_ms_per_frame']:9.3f} {r['ratio_to_every_frame']:6.2f} "
              f"{r['predicted_share']:9.1%} {r['widened_per_100']:8.1f} {r['global_per_100']:7.1f} {r['lost']:5d} "
              f"{r['ball_error_rms_px']:11.4f}")
    doc = {"bench": "gap_cost", "frames": args.frames, "repeats": args.repeats, "seed": args.seed,
           "machine": {"cpus": os.cpu_count(), "platform": platform.platform()}, "schedules": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
