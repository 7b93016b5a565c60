"""A/B of the DIC tracker's per-frame cost: this working tree against a git revision, in one run.

    scripts/py bench/bench_dic_ab.py [--baseline REV] [--frames 400] [--rounds 5]

The baseline's packages (``git archive REV src``) go into a temp folder; each side tracks the same frames of the
live benchmark's recording (bench_live.cached_recording: 1500 frames, 480 x 160 px, ball mesh 4 + structure mesh 24
points of 31 px) in its own process, one core (BLAS and OpenCV threads 1), after tracking the first 50 frames to
warm up (imports, caches, the compiled kernels). Sides alternate for ``--rounds`` rounds; the medians and their
ratio are printed and written to bench/results/dic_ab.json. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

CHILD = r"""
import json, sys, time
import cv2
cv2.setNumThreads(1)
from vibro_io.recording import open_recording
from vibro_dic.tracker import DicTracker
import vibro_dic.tracker as t
rec = open_recording(sys.argv[1])
n = int(sys.argv[2])
images = [f.image for _, f in zip(range(n + 50), rec.frames)]
tracker = DicTracker.for_rig(images[0], rec.rig)
frame_time = rec.rig.camera.frame_time_s
for k in range(50):
    tracker.track_image(k, frame_time(k), images[k])
t0 = time.perf_counter()
for k in range(50, n + 50):
    tracker.track_image(k, frame_time(k), images[k])
ms = 1e3 * (time.perf_counter() - t0) / n
print(json.dumps({"ms_per_frame": ms, "tracker_module": t.__file__}))
"""


def export_revision(rev: str, folder: Path) -> Path:
    """The ``src`` folder of git revision ``rev``, extracted into ``folder``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder / "src"


def side_env(src: Path | None) -> dict[str, str]:
    """The environment of one side: ``src``'s packages ahead of the working tree's (None: the working tree)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    if src is not None:
        paths = [str(p) for p in sorted(src.iterdir()) if p.is_dir()]
        env["PYTHONPATH"] = os.pathsep.join(paths + [env.get("PYTHONPATH", "")])
    return env


def run_side(env: dict[str, str], rec: Path, frames: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(rec), str(frames)], env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    from bench_live import cached_recording

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default="HEAD", help="git revision to compare with (default HEAD)")
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.baseline], check=True,
                         capture_output=True, text=True).stdout.strip()
    rec = cached_recording(1500)
    with tempfile.TemporaryDirectory(prefix="vibro-ab-") as tmp:
        sides = {"baseline": side_env(export_revision(rev, Path(tmp))), "this tree": side_env(None)}
        times: dict[str, list[float]] = {name: [] for name in sides}
        modules = {}
        for r in range(args.rounds):
            for name, env in sides.items():
                res = run_side(env, rec, args.frames)
                times[name].append(res["ms_per_frame"])
                modules[name] = res["tracker_module"]
            print(f"round {r + 1}: " + ", ".join(f"{n} {t[-1]:.3f} ms/frame" for n, t in times.items()), flush=True)
    med = {name: statistics.median(t) for name, t in times.items()}
    ratio = med["baseline"] / med["this tree"]
    verdict = f"{ratio:.2f}x faster" if ratio >= 1 else f"{1 / ratio:.2f}x slower"
    print(f"median ms/frame: baseline {rev} {med['baseline']:.3f}, this tree {med['this tree']:.3f}: {verdict}")
    result = {"command": " ".join(sys.argv), "baseline": rev, "frames": args.frames, "rounds": args.rounds,
              "recording": str(rec), "ms_per_frame": times, "median_ms_per_frame": med,
              "baseline_over_this_tree": ratio, "tracker_modules": modules}
    out = BENCH / "results" / "dic_ab.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
