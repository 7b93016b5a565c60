"""Benchmark of the plain ball's outline tracking (vibro_dic.outline) beside the DIC mesh: frames/s per core.

Run: scripts/py bench/bench_outline.py [--frames 400] [--repeats 3] [--seed 2]
Prints a table and writes bench/results/outline.json. Everything is measured in this run, on one core
(BLAS/OpenCV threads pinned to 1), as CPU time of this process (time.process_time: other jobs on a shared
machine slow the wall clock, not the CPU seconds), best of the repeats:

- a ``vibro synth --ball-surface plain`` recording (a backlit plain ball) tracked by its outline (rig.yaml
  ``dic.ball_method: outline``, the box the synth writes) and by the DIC mesh on the same box (31 px
  subsets every 10 px, the way a user without the outline method would try it);
- the same motion (same seed) with a speckled ball tracked by its DIC mesh (the ROI inside the ball), the
  method's ordinary use.

Per configuration: the ball tracker alone (frames/s per core, and the ratio to the outline), the whole
frame (ball + the structure's DIC mesh, what ``vibro track`` does per frame, reading and decoding excluded),
frames lost, and the ball's error against the synth's truth (RMS over the frames tracked, px, rows).
Trackers are built as ``vibro track`` builds them (``DicTracker.for_rig``, the texture check's usable
subsets).
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
import yaml  # noqa: E402

cv2.setNumThreads(1)
REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "results" / "outline.json"


class _Timed:
    """A body tracker whose ``track`` calls add up their CPU seconds (the rest passes through)."""

    def __init__(self, inner):
        self.inner = inner
        self.cpu_s = 0.0

    def track(self, image, k):
        t = time.process_time()
        res = self.inner.track(image, k)
        self.cpu_s += time.process_time() - t
        return res

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _recording(base: Path, name: str, frames: int, seed: int, surface: str, ball_method: str | None = None) -> Path:
    from vibro_sim.synth import SynthConfig, synthesize

    rec = base / name
    truth = synthesize(rec, SynthConfig(frames=frames, accel=False, ball_surface=surface, seed=seed), progress=False)
    (rec / "truth.json").write_text(json.dumps({"ball_mm": truth["frames"]["ball_mm"],
                                                "mm_per_px": truth["image"]["mm_per_px"]}))
    if ball_method is not None:
        rig = yaml.safe_load((rec / "rig.yaml").read_text())
        rig["dic"]["ball_method"] = ball_method
        (rec / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    return rec


def _one_pass(rec: Path, images: list[np.ndarray]) -> dict:
    """Track ``images`` (frame 0 first) of recording ``rec`` once; CPU seconds of the ball, the structure, the
    whole frame; frames lost; the ball's error against the truth."""
    from vibro_dic.texture import TextureError
    from vibro_dic.tracker import DicTracker, reference_texture
    from vibro_io.recording import open_recording

    recording = open_recording(rec)
    tracker = DicTracker.for_rig(images[0], recording.rig)
    try:
        texture = reference_texture(recording)
        tracker.use_texture(texture)
        body = texture.bodies["ball"]
        texture_note = f"texture check passed: {body.n_usable} of {len(body.points)} ball points usable"
    except TextureError as exc:
        texture_note = f"texture check refused ({str(exc)[:160]}...): timed with every subset"
    tracker.ball, tracker.structure = _Timed(tracker.ball), _Timed(tracker.structure)
    fps = recording.rig.camera.fps
    down, lost = [], 0
    t0 = time.process_time()
    for k, img in enumerate(images):
        ft = tracker.track_image(k, k / fps, img)
        lost += int(ft.lost)
        down.append(ft.ball_mm)
    whole = time.process_time() - t0
    truth = json.loads((rec / "truth.json").read_text())
    true = np.asarray(truth["ball_mm"][:len(images)])
    err_px = (np.asarray(down) - (true - true[0])) / truth["mm_per_px"]
    ok = np.isfinite(err_px)
    ok[0] = False  # frame 0 is the reference itself
    rms = float(np.sqrt(np.mean(err_px[ok] ** 2))) if ok.any() else math.nan
    n_points = len(tracker.ball.points)
    return {"ball_cpu_s": tracker.ball.cpu_s, "structure_cpu_s": tracker.structure.cpu_s, "frame_cpu_s": whole,
            "frames_lost": lost, "ball_error_rms_px": rms, "ball_points": n_points, "texture": texture_note}


def _load(rec: Path, frames: int) -> list[np.ndarray]:
    from vibro_io.frames import read_image

    paths = sorted((rec / "frames").iterdir())[:frames]
    return [read_image(p).astype(np.float32) for p in paths]


CONFIGS = (  # name, recording, what it measures
    ("outline, plain ball", "plain", "the outline (rig.yaml dic.ball_method outline, the synth's box)"),
    ("DIC mesh, plain ball", "plain_mesh", "DIC subsets on the same box around the plain ball"),
    ("DIC mesh, speckled ball", "speckle", "DIC subsets inside a speckled ball (the same motion)"),
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="Writes bench/results/outline.json (see docs/benchmarks.md).")
    ap.add_argument("--frames", type=int, default=400, help="frames per recording (default 400)")
    ap.add_argument("--repeats", type=int, default=3, help="passes per configuration, the fastest kept (default 3)")
    ap.add_argument("--seed", type=int, default=2, help="synth seed, the same motion for all (default 2)")
    ap.add_argument("--out", type=Path, default=OUT, help=f"JSON to write (default {OUT.relative_to(REPO)})")
    args = ap.parse_args(argv)
    if args.frames < 10 or args.repeats < 1:
        ap.error("--frames must be >= 10 and --repeats >= 1")
    base = Path(tempfile.mkdtemp(prefix="bench_outline_"))
    try:
        recs = {"plain": _recording(base, "plain", args.frames, args.seed, "plain"),
                "speckle": _recording(base, "speckle", args.frames, args.seed, "speckle")}
        recs["plain_mesh"] = base / "plain_mesh"
        shutil.copytree(recs["plain"], recs["plain_mesh"])
        rig = yaml.safe_load((recs["plain_mesh"] / "rig.yaml").read_text())
        rig["dic"].pop("ball_method", None)  # the default, mesh, on the outline's box
        (recs["plain_mesh"] / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
        images = {"plain": _load(recs["plain"], args.frames), "speckle": _load(recs["speckle"], args.frames)}
        images["plain_mesh"] = images["plain"]
        rows = []
        for name, key, what in CONFIGS:
            passes = [_one_pass(recs[key], images[key]) for _ in range(args.repeats)]
            best = min(passes, key=lambda p: p["ball_cpu_s"])
            n = len(images[key])
            rows.append({"config": name, "what": what, "frames": n, "repeats": args.repeats,
                         "ball_frames_per_s_per_core": n / best["ball_cpu_s"],
                         "ball_ms_per_frame": 1e3 * best["ball_cpu_s"] / n,
                         "whole_frame_frames_per_s_per_core": n / min(p["frame_cpu_s"] for p in passes),
                         "structure_ms_per_frame": 1e3 * best["structure_cpu_s"] / n,
                         **{k: best[k] for k in ("frames_lost", "ball_error_rms_px", "ball_points", "texture")}})
        ref = rows[0]["ball_frames_per_s_per_core"]
        for r in rows:
            r["ball_speed_over_outline"] = r["ball_frames_per_s_per_core"] / ref
    finally:
        shutil.rmtree(base, ignore_errors=True)
    print(f"{'configuration':26s} {'ball fr/s/core':>14s} {'x outline':>9s} {'ball ms/fr':>10s} "
          f"{'frame fr/s/core':>15s} {'points':>6s} {'lost':>5s} {'ball RMS px':>11s}")
    for r in rows:
        print(f"{r['config']:26s} {r['ball_frames_per_s_per_core']:14.0f} {r['ball_speed_over_outline']:9.2f} "
              f"{r['ball_ms_per_frame']:10.3f} {r['whole_frame_frames_per_s_per_core']:15.0f} {r['ball_points']:6d} "
              f"{r['frames_lost']:5d} {r['ball_error_rms_px']:11.4f}")
    for r in rows:
        print(f"  {r['config']}: {r['texture']}")
    doc = {"bench": "bench_outline.py", "when": time.strftime("%Y-%m-%d %H:%M:%S"),
           "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                       "python": platform.python_version(), "load_average": list(os.getloadavg())},
           "timing": "CPU seconds of this process (time.process_time), one thread, best of the repeats; frame "
                     "reading and decoding excluded",
           "frames": args.frames, "seed": args.seed, "configs": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
