"""Recordings and analyses made once per test run and shared by the test files that only read them.

A synthetic recording and its analysis cost seconds to tens of seconds; where two test files need the same one,
:func:`shared_dir` makes it once per ``pytest`` run, also under pytest-xdist: in the base temp directory all
workers of the run share, under a file lock, so the second worker waits for the first and reads what it made.
Nothing made here may be modified: a test that changes a recording copies it first.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import yaml

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]


def shared_dir(tmp_path_factory, name: str, make: Callable[[Path], None]) -> Path:
    """The folder ``name`` of this test run's shared temp directory, made by ``make(folder)`` (into an empty
    folder) the first time any worker asks for it. A make that failed half-way is kept beside, renamed (its files
    say why), and made again."""
    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the base temp directory all workers of this run share
    folder = shared / "shared_runs" / name
    folder.parent.mkdir(exist_ok=True)
    done = folder.with_name(f"{name}.done")
    with open(folder.with_name(f"{name}.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            if folder.exists():
                folder.rename(folder.with_name(f"{name}.failed-{time.time_ns()}"))
            folder.mkdir()
            make(folder)
            done.touch()
    return folder


def _vibro(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=600, env=dict(os.environ),
                          cwd=ROOT)


#: the barrel lens of tests/test_optics.py and tests/test_camera_calibration.py (its scale ~1.5 % lower at the
#: plates than at the image centre), the take's length and seed
LENS_K1, LENS_FRAMES, LENS_SEED = -0.18, 700, 3


def lens_recordings(tmp_path_factory) -> dict:
    """One recording through the lens (``vibro synth --lens-k1``, no accelerometers) analysed with its calibration
    (``calibrated``) and, from a copy whose rig.yaml lost ``camera.calibration`` and its camera_info.yaml (the lab
    that forgot), without it (``forgotten``): the same frames both ways. Per case: ``rec`` (the recording), ``out``
    (``vibro analyze --no-report`` of it), ``doc`` (its results.json) and ``stdout``; ``truth`` (the lens take's
    truth file)."""

    def make(base: Path) -> None:
        calibrated = base / "calibrated"
        p = _vibro("synth", "--out", str(calibrated), "--frames", str(LENS_FRAMES), "--seed", str(LENS_SEED),
                   "--lens-k1", str(LENS_K1), "--no-accel", "--no-progress")
        assert p.returncode == 0, p.stderr
        forgotten = base / "forgotten"
        shutil.copytree(calibrated, forgotten)
        rig = yaml.safe_load((forgotten / "rig.yaml").read_text())
        assert rig["camera"].pop("calibration") == "camera_info.yaml"   # the premise: synth named it
        (forgotten / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
        (forgotten / "camera_info.yaml").unlink()
        for name in ("forgotten", "calibrated"):
            a = _vibro("analyze", str(base / name), "--out", str(base / f"{name}_out"), "--no-progress",
                       "--no-report")
            assert a.returncode == 0, a.stderr
            (base / f"{name}.stdout").write_text(a.stdout)

    base = shared_dir(tmp_path_factory, "lens", make)
    runs = {name: {"rec": base / name, "out": base / f"{name}_out",
                   "doc": json.loads((base / f"{name}_out" / "results.json").read_text()),
                   "stdout": (base / f"{name}.stdout").read_text()} for name in ("forgotten", "calibrated")}
    return {**runs, "truth": json.loads((base / "calibrated.truth.json").read_text())}
