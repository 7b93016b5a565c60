"""Memory and time against the recording's length: ``vibro analyze`` of 1,500 to 60,000 frames.

For each length a default synthetic recording (``vibro synth --frames N``: 1000 fps, 22 Hz, accelerometers
at 50 kHz in accel.csv) is written, then run as children of this script, one at a time, each timed and its
peak resident memory read from ``os.wait4`` (the child's own ru_maxrss):

- ``vibro track`` (DIC alone): the baseline measured in the same run, the ratio column divides by it;
- ``vibro analyze --track dic.csv`` (the analysis after DIC: accelerometers read, identification,
  simulation, discrepancy, report);
- ``vibro analyze`` (everything, as a user runs it).

The columns: synth time, then peak RSS (MiB) and wall time (s) of each, analyze's peak RSS over track's,
analyze's peak RSS per frame, and the memory each added frame costs (the slope of analyze's peak RSS
between consecutive lengths: constant when the memory is linear in the length). ``--only-analyze``
skips the first two runs (the long sweep in less time). The recordings are deleted after use (60,000
frames take 3.2 GB) unless ``--keep``; ``--reuse`` takes an existing recording of the same length in
``--dir`` instead of writing it again (its synth time is then not measured).

``--lab-files``: the path a lab takes from its own camera and DAQ files (issue 38 item 5). ``vibro synth
--lab-files`` writes the take as an 8-bit Photron MRAW (video.mraw + video.cih) and an NI TDMS of the
accelerometers (50 kHz), without rig.yaml; then, each a child timed alone: ``vibro init RUN --ball-diameter-mm
4.77 --gap-mm 16.6`` (which finds the TDMS beside the video and names it in rig.yaml), and ``vibro analyze RUN
--out OUT`` (with its report). The goal: init + analyze within
60 s and 1 GB peak RSS each on 2 cores. The rows go to the ``lab_files`` key of --out (the rest of the file
is kept), with the load average (1 min) before and after each step: the machine may be shared.

Run: scripts/py bench/bench_length.py [--lengths 1500,5000,20000,60000] [--only-analyze]
     [--dir /tmp/vibro_bench_length] [--keep] [--reuse] -> table + bench/results/length.json
     scripts/py bench/bench_length.py --lab-files --lengths 1500,5000,20000 -> table + length.json "lab_files"
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VIBRO = str(ROOT / "vibro")
LENGTHS = (1500, 5000, 20000, 60000)
LAB_LENGTHS = (1500, 5000, 20000)
MIB = 1024.0 * 1024.0
BALL_DIAMETER_MM, GAP_MM = "4.77", "16.6"   # the synthetic rig's two lengths, as a lab knows them
GOAL = {"wall_s": 60.0, "rss_mib": 1024.0}


def run_child(args: list[str]) -> dict:
    """Run ``./vibro ARGS`` as a child: {"rss_mib", "wall_s", "rc"} (ru_maxrss: KiB on Linux); raises
    with its stderr when it fails."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([VIBRO, *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    rc = os.waitstatus_to_exitcode(status)
    proc.returncode = rc
    if rc != 0:
        raise RuntimeError(f"vibro {' '.join(args)} failed ({rc}): {err.strip()[-2000:]}")
    return {"rss_mib": usage.ru_maxrss * 1024.0 / MIB, "wall_s": wall}


def results_summary(out: Path) -> dict:
    """What the analysis produced (so a run that lost its results does not pass for a fast one)."""
    doc = json.loads((out / "results.json").read_text(encoding="utf-8"))
    disc = doc.get("discrepancy") or {}
    return {"impacts": len(doc.get("impacts") or []), "flights": len(doc.get("flights") or []),
            "discrepancy": "error" if disc.get("error") else "skipped" if disc.get("skipped") else "ok",
            "warnings": len(doc.get("warnings") or [])}


def one_length(n: int, work: Path, seed: int, only_analyze: bool, keep: bool, reuse: bool) -> dict:
    rec = work / f"rec{n}"
    row: dict = {"frames": n}
    if reuse and (rec / "rig.yaml").is_file() and (rec / "frames").is_dir() and \
            sum(1 for _ in (rec / "frames").iterdir()) == n:
        row["synth"] = None
        print(f"[{n}] reusing {rec}", file=sys.stderr, flush=True)
    else:
        print(f"[{n}] vibro synth", file=sys.stderr, flush=True)
        row["synth"] = run_child(["synth", "--out", str(rec), "--frames", str(n), "--seed", str(seed), "--overwrite",
                                  "--no-progress"])
    try:
        if not only_analyze:
            print(f"[{n}] vibro track", file=sys.stderr, flush=True)
            row["track"] = run_child(["track", str(rec), "--out", str(work / f"track{n}"), "--overwrite",
                                      "--no-progress"])
            print(f"[{n}] vibro analyze --track", file=sys.stderr, flush=True)
            row["analyze_after_dic"] = run_child(["analyze", str(rec), "--track", str(work / f"track{n}" / "dic.csv"),
                                                  "--out", str(work / f"after{n}"), "--overwrite", "--no-progress"])
            row["analyze_after_dic"].update(results_summary(work / f"after{n}"))
        print(f"[{n}] vibro analyze", file=sys.stderr, flush=True)
        row["analyze"] = run_child(["analyze", str(rec), "--out", str(work / f"analyze{n}"), "--overwrite",
                                    "--no-progress"])
        row["analyze"].update(results_summary(work / f"analyze{n}"))
    finally:
        if not keep:
            for d in (rec, work / f"track{n}", work / f"after{n}", work / f"analyze{n}"):
                shutil.rmtree(d, ignore_errors=True)
            Path(f"{rec}.truth.json").unlink(missing_ok=True)
    a = row["analyze"]
    row["analyze_kib_per_frame"] = a["rss_mib"] * 1024.0 / n
    if "track" in row:
        row["analyze_over_track_rss"] = a["rss_mib"] / row["track"]["rss_mib"]
        row["analyze_over_track_wall"] = a["wall_s"] / row["track"]["wall_s"]
    return row


def _load() -> float:
    return os.getloadavg()[0]


def timed_step(args: list[str]) -> dict:
    """:func:`run_child` with the 1-minute load average before and after."""
    before = _load()
    res = run_child(args)
    res["load_before"], res["load_after"] = before, _load()
    return res


def one_length_lab(n: int, work: Path, seed: int, keep: bool) -> dict:
    """Lab files of ``n`` frames: synth --lab-files, then vibro init and vibro analyze, each timed alone."""
    rec, out = work / f"lab{n}", work / f"lab{n}_out"
    row: dict = {"frames": n}
    print(f"[{n}] vibro synth --lab-files", file=sys.stderr, flush=True)
    row["synth"] = timed_step(["synth", "--out", str(rec), "--frames", str(n), "--seed", str(seed), "--lab-files",
                               "--overwrite", "--no-progress"])
    row["mraw_mib"] = (rec / "video.mraw").stat().st_size / MIB
    row["tdms_mib"] = (rec / "accel.tdms").stat().st_size / MIB
    try:
        print(f"[{n}] vibro init", file=sys.stderr, flush=True)
        row["init"] = timed_step(["init", str(rec), "--ball-diameter-mm", BALL_DIAMETER_MM, "--gap-mm", GAP_MM])
        print(f"[{n}] vibro analyze", file=sys.stderr, flush=True)
        row["analyze"] = timed_step(["analyze", str(rec), "--out", str(out), "--overwrite", "--no-progress"])
        row["analyze"].update(results_summary(out))
        truth = json.loads(Path(f"{rec}.truth.json").read_text(encoding="utf-8"))
        row["analyze"]["true_impacts"] = len(truth["impacts"])
    finally:
        if not keep:
            for d in (rec, out):
                shutil.rmtree(d, ignore_errors=True)
            Path(f"{rec}.truth.json").unlink(missing_ok=True)
    steps = (row["init"], row["analyze"])
    row["user_wall_s"] = sum(s["wall_s"] for s in steps)
    row["user_peak_rss_mib"] = max(s["rss_mib"] for s in steps)
    row["goal_met"] = row["user_wall_s"] <= GOAL["wall_s"] and row["user_peak_rss_mib"] <= GOAL["rss_mib"]
    return row


def print_lab_table(rows: list[dict]) -> None:
    print(f"\n{'frames':>7} {'synth s':>8} {'MiB':>5} | {'init MiB':>8} {'s':>5} | {'analyze MiB':>11} {'s':>6} "
          f"{'impacts':>8} | {'init+analyze s':>14} {'goal':>4} | {'load':>9}")
    for r in rows:
        i, a = r["init"], r["analyze"]
        loads = [s[k] for s in (r["synth"], i, a) for k in ("load_before", "load_after")]
        goal = "met" if r["goal_met"] else "no"
        print(f"{r['frames']:>7} {r['synth']['wall_s']:>8.0f} {r['synth']['rss_mib']:>5.0f} | "
              f"{i['rss_mib']:>8.0f} {i['wall_s']:>5.1f} | {a['rss_mib']:>11.0f} {a['wall_s']:>6.1f} "
              f"{a['impacts']:>3}/{a['true_impacts']:<4} | {r['user_wall_s']:>14.1f} {goal:>4} | "
              f"{min(loads):.1f}-{max(loads):.1f}")


def main_lab(args: argparse.Namespace) -> int:
    """``--lab-files``: the rows into the ``lab_files`` key of ``args.out`` (the file's other keys kept)."""
    lengths = sorted({int(x) for x in args.lengths.split(",") if x.strip()}) if args.lengths else list(LAB_LENGTHS)
    work = Path(args.dir)
    work.mkdir(parents=True, exist_ok=True)
    rows, t0 = [], time.perf_counter()
    for n in lengths:
        rows.append(one_length_lab(n, work, args.seed, args.keep))
        r = rows[-1]
        print(f"[{n}] init {r['init']['wall_s']:.1f} s, analyze {r['analyze']['wall_s']:.1f} s "
              f"{r['analyze']['rss_mib']:.0f} MiB, {r['analyze']['impacts']} impacts", file=sys.stderr, flush=True)
    print_lab_table(rows)
    path = Path(args.out)
    doc = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {"benchmark": "length"}
    doc["lab_files"] = {
        "what": "a lab's path: vibro synth --lab-files (8-bit MRAW + .cih, NI TDMS at 50 kHz, no rig.yaml), then "
                "vibro init RUN --ball-diameter-mm 4.77 --gap-mm 16.6 (it names the TDMS in rig.yaml), vibro "
                "analyze RUN --out OUT (report included); each a child process timed alone",
        "goal": {"init_plus_analyze_wall_s": GOAL["wall_s"], "peak_rss_mib": GOAL["rss_mib"]},
        "settings": {"lengths": lengths, "seed": args.seed, "fps": 1000.0, "cpus": os.cpu_count(),
                     "python": platform.python_version()},
        "rss": "peak resident set size of the child (os.wait4 ru_maxrss), MiB",
        "load": "1-minute load average before and after each step (load_before, load_after)",
        "wall_s": time.perf_counter() - t0, "rows": rows}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    print(f"wrote {path} (key lab_files)")
    return 0


def _f(x, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def print_table(rows: list[dict]) -> None:
    print(f"\n{'frames':>7} {'synth s':>8} | {'track MiB':>9} {'s':>6} | {'after DIC MiB':>13} {'s':>6} | "
          f"{'analyze MiB':>11} {'s':>6} | {'/track':>6} | {'KiB/frame':>9} {'KiB/added frame':>15}")
    prev = None
    for r in rows:
        t, m, a = r.get("track"), r.get("analyze_after_dic"), r["analyze"]
        slope = None if prev is None else ((a["rss_mib"] - prev["analyze"]["rss_mib"]) * 1024.0
                                           / (r["frames"] - prev["frames"]))
        r["analyze_kib_per_added_frame"] = slope
        print(f"{r['frames']:>7} {_f(r['synth'] and r['synth']['wall_s'], '.0f'):>8} | "
              f"{_f(t and t['rss_mib'], '.0f'):>9} {_f(t and t['wall_s'], '.1f'):>6} | "
              f"{_f(m and m['rss_mib'], '.0f'):>13} {_f(m and m['wall_s'], '.1f'):>6} | "
              f"{a['rss_mib']:>11.0f} {a['wall_s']:>6.1f} | {_f(r.get('analyze_over_track_rss'), '.2f'):>6} | "
              f"{r['analyze_kib_per_frame']:>9.1f} {_f(slope, '.1f'):>15}")
        prev = r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", default=None,
                    help=f"frames, comma separated (default {','.join(map(str, LENGTHS))}; --lab-files "
                         f"{','.join(map(str, LAB_LENGTHS))})")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--only-analyze", action="store_true", help="skip vibro track and analyze --track")
    ap.add_argument("--dir", default="/tmp/vibro_bench_length", help="working folder for the recordings")
    ap.add_argument("--keep", action="store_true", help="keep the recordings and outputs")
    ap.add_argument("--reuse", action="store_true", help="use a recording of the same length already in --dir")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "length.json"))
    ap.add_argument("--lab-files", action="store_true",
                    help="a lab's path: synth --lab-files, vibro init, vibro analyze (key lab_files of --out)")
    args = ap.parse_args(argv)
    if args.lab_files:
        return main_lab(args)
    lengths = sorted({int(x) for x in (args.lengths or ",".join(map(str, LENGTHS))).split(",") if x.strip()})
    work = Path(args.dir)
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    t0 = time.perf_counter()
    for n in lengths:
        rows.append(one_length(n, work, args.seed, args.only_analyze, args.keep, args.reuse))
        a = rows[-1]["analyze"]
        print(f"[{n}] vibro analyze: {a['rss_mib']:.0f} MiB, {a['wall_s']:.1f} s, {a['impacts']} impacts, "
              f"discrepancy {a['discrepancy']}", file=sys.stderr, flush=True)
    print_table(rows)
    out = {"benchmark": "length", "settings": {"lengths": lengths, "seed": args.seed, "fps": 1000.0,
                                               "only_analyze": args.only_analyze, "cpus": os.cpu_count(),
                                               "python": platform.python_version()},
           "baseline": "vibro track (DIC alone) of the same recording, same run",
           "rss": "peak resident set size of the child (os.wait4 ru_maxrss), MiB",
           "wall_s": time.perf_counter() - t0, "rows": rows}
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1), encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
