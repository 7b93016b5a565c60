"""``vibro track`` and ``vibro noise`` subcommands (DIC of a recording)."""

from __future__ import annotations

import argparse
import json
import logging
import sys

from vibro_dic.cluster import add_cluster_args
from vibro_dic.methods import METHODS
from vibro_dic.noise import DEFAULT_SPLIT_HZ, noise_study
from vibro_io.dictrack import DicTrack, write_dic_csv
from vibro_io.outputs import atomic_path, atomic_write_text, prepare_output_dir, prepare_output_file
from vibro_io.recording import open_recording

log = logging.getLogger(__name__)

DIC_CSV = "dic.csv"  # the track file of "vibro track" and "vibro analyze"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("track", help="DIC-track ball and structure; writes DIR/dic.csv")
    p.add_argument("recording", help="recording directory (rig.yaml + frames/ or video)")
    p.add_argument("--out", required=True,
                   help="output folder (created; must be empty unless --overwrite); dic.csv goes there")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the dic.csv of an earlier 'vibro track' in --out (refused if it holds other files)")
    _common(p)
    add_cluster_args(p)
    p.set_defaults(func=run_track)

    q = sub.add_parser("noise", help="noise study of a motionless recording (paper Fig. 17)")
    q.add_argument("recording", help="recording directory of a motionless rig")
    q.add_argument("--split-hz", type=float, default=DEFAULT_SPLIT_HZ,
                   help=f"low/high-frequency split (Hz, default {DEFAULT_SPLIT_HZ:g})")
    q.add_argument("--json", help="also write the study to this JSON file (must not exist unless --overwrite)")
    q.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    _common(q)
    q.set_defaults(func=run_noise)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--method", choices=METHODS, default="icgn",
                   help="sub-pixel method: icgn (default) or parabolic (baseline)")
    p.add_argument("--zncc-min", type=float, default=0.6, help="ZNCC threshold of a valid point (default 0.6)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _progress(args: argparse.Namespace) -> bool:
    return not args.no_progress and sys.stderr.isatty()


class _Counter:
    """Pass rows through while counting frames, tracked frames and lost frames."""

    def __init__(self, rows):
        self.rows = rows
        self.n = self.lost = 0
        self.first_lost: list[int] = []

    def __iter__(self):
        for r in self.rows:
            self.n += 1
            if r.lost:
                self.lost += 1
                if len(self.first_lost) < 5:
                    self.first_lost.append(r.frame)
            yield r


def run_track(args: argparse.Namespace) -> int:
    from vibro_dic.chunked import track_rows  # the tracker and its compiled kernels: only when a track is made

    rec = open_recording(args.recording)
    out = prepare_output_dir(args.out, overwrite=args.overwrite, owned=(DIC_CSV,), command="track",
                             inputs=[rec.path])
    rows = _Counter(track_rows(rec, workers=args.workers, scheduler=args.scheduler, method=args.method,
                               progress=_progress(args), zncc_min=args.zncc_min))
    with atomic_path(out / DIC_CSV) as tmp:
        write_dic_csv(tmp, rows)
    lost = f" (first lost: {', '.join(map(str, rows.first_lost))})" if rows.lost else ""
    print(f"vibro track: {rows.n} frames in, {rows.n - rows.lost} tracked, {rows.lost} lost{lost} "
          f"-> {out / 'dic.csv'}")
    return 0


def run_noise(args: argparse.Namespace) -> int:
    from vibro_dic.tracker import track_recording  # the tracker and its compiled kernels: only when tracking

    rec = open_recording(args.recording)
    if args.json:
        prepare_output_file(args.json, overwrite=args.overwrite)
    track = DicTrack.from_frames(track_recording(rec, method=args.method, progress=_progress(args),
                                                 zncc_min=args.zncc_min))
    study = noise_study(track, rec.rig.camera.fps, rec.rig.camera.mm_per_px, args.split_hz)
    print(f"noise study of {rec.path}: {study['n_frames']} frames, {study['n_lost']} lost, "
          f"split at {study['split_hz']:g} Hz (low = Butterworth-4 zero-phase low-pass)")
    print(f"{'body':<10} {'std_mm':>10} {'high_mm':>10} {'low_mm':>10} {'p2p_mm':>10} "
          f"{'std_px':>8} {'high_px':>8} {'low_px':>8}")
    for body in ("ball", "structure"):
        s = study[body]
        print(f"{body:<10} {s['std_mm']:10.2e} {s['high_std_mm']:10.2e} {s['low_std_mm']:10.2e} "
              f"{s['peak_to_peak_mm']:10.2e} {s['std_px']:8.4f} {s['high_std_px']:8.4f} {s['low_std_px']:8.4f}")
    if args.json:
        atomic_write_text(args.json, json.dumps(study, indent=2) + "\n")
    return 0
