"""``vibro init`` on synthetic recordings (vibro_sim.synth) of several scales, ball sizes and ball positions.

Ground truth: the synth's true rig.yaml (kept aside) and its truth file (scale, ball radius, ball and
structure heights per frame). Checked: the proposed rig loads (parse_rig, ROIs in the image and
holding their subsets), its scale is within 1 % of the truth and within 3 of its own stated sigmas,
the ROIs sit on the ball / a plate over the whole recording, and ``vibro analyze`` gives the same
impacts from the proposed rig as from the true one. Refusals: exit 2 and one line, nothing written.
"""

from __future__ import annotations

import math
import re
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from lab_writers import write_mraw  # noqa: E402

from vibro_app.cli import main  # noqa: E402
from vibro_io.frames import read_image  # noqa: E402
from vibro_io.recording import open_recording  # noqa: E402
from vibro_io.rig import load_rig  # noqa: E402

FPS = 1000.0
GAP_MM = 16.6
# several scales (mm/px), ball sizes (mm) and image sizes; the seed sets the drive's phase at frame 0,
# hence where the ball and the plates are in frame 0
CASES = {
    "fine_scale": dict(seed=2, mm_per_px=0.05, height_px=600),
    "big_ball": dict(seed=4, mm_per_px=0.075, ball_diameter_mm=8.0),
    "small_ball_wide": dict(seed=7, mm_per_px=0.06, ball_diameter_mm=4.0, width_px=200),
}


def _cors(out: Path) -> dict[str, np.ndarray]:
    rows = np.genfromtxt(out / "impacts.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    return {k: np.atleast_1d(rows[k]) for k in ("t", "plate", "cor", "cor_std")}


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    """Per case: the recording (proposed rig.yaml in it), the truth, the synth options, and the impacts
    analysed with the true rig (a copy of the recording) and with the proposed one."""
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("init")
    out = {}
    for name, kw in CASES.items():
        rec = base / name
        truth = synthesize(rec, SynthConfig(frames=300, accel=False, **kw), progress=False)
        true_rec = base / f"{name}_true"
        shutil.copytree(rec, true_rec)  # the same frames with the synth's own rig.yaml
        (rec / "rig.yaml").unlink()
        d_mm = kw.get("ball_diameter_mm", 4.77)
        code = main(["init", str(rec), "--ball-diameter-mm", str(d_mm), "--gap-mm", str(GAP_MM), "--fps", str(FPS)])
        assert code == 0, name
        runs = {}
        for which, r in (("true", true_rec), ("proposed", rec)):
            assert main(["analyze", str(r), "--out", str(base / f"{name}_{which}_out"), "--no-report",
                         "--no-progress"]) == 0
            runs[which] = _cors(base / f"{name}_{which}_out")
        out[name] = dict(rec=rec, truth=truth, kw=kw, runs=runs)
    return out


def _stated_scale_std(rig_text: str) -> float:
    """The relative 1-sigma of the written scale, from the rig.yaml's comment."""
    m = re.search(r"scale written: .* mm/px \+- ([0-9.]+) %", rig_text)
    assert m, "rig.yaml states the written scale's uncertainty"
    return float(m.group(1)) / 100.0


@pytest.mark.parametrize("name", list(CASES))
def test_scale_within_one_percent_and_its_stated_sigma(cases, name):
    c = cases[name]
    rig = load_rig(c["rec"] / "rig.yaml")
    true_scale = c["truth"]["image"]["mm_per_px"]
    err = rig.camera.mm_per_px / true_scale - 1.0
    sigma = _stated_scale_std((c["rec"] / "rig.yaml").read_text())
    print(f"{name}: scale error {100 * err:+.3f} % (stated 1 sigma {100 * sigma:.3f} %)")
    assert abs(err) <= 0.01
    assert abs(err) <= 3.0 * sigma + 1e-4  # the stated uncertainty covers the actual error


@pytest.mark.parametrize("name", list(CASES))
def test_rois_hold_the_ball_and_a_plate_over_the_whole_recording(cases, name):
    c = cases[name]
    rec = open_recording(c["rec"])  # the loader accepts the proposal: ROIs in the image, >= one subset each
    truth, rig = c["truth"], rec.rig
    img = truth["image"]
    s, row_mid, col_mid = img["mm_per_px"], img["row_mid"], (img["width_px"] - 1) / 2
    ball_mm, struct_mm = np.array(truth["frames"]["ball_mm"]), np.array(truth["frames"]["structure_mm"])
    # ball ROI: its corners inside the true disc at frame 0, less the edge blur's 3 sigma (1.5 px in the synth)
    b = rig.dic.ball_roi
    cy0 = row_mid - ball_mm[0] / s
    corners = [(b.x, b.y), (b.x + b.w - 1, b.y), (b.x, b.y + b.h - 1), (b.x + b.w - 1, b.y + b.h - 1)]
    assert max(math.hypot(x - col_mid, y - cy0) for x, y in corners) <= img["ball_radius_px"] - 4.5
    # ...and it follows the ball inside the image over every frame of the recording
    down = (ball_mm[0] - ball_mm) / s
    assert b.y + down.min() >= 0 and b.y + b.h - 1 + down.max() <= img["height_px"] - 1
    # structure ROI: on a plate (beyond its true edge + 4.5 px) at frame 0 and in the image over every frame
    r = rig.dic.structure_roi
    top_edge = row_mid - struct_mm[0] / s - 0.5 * GAP_MM / s
    bottom_edge = top_edge + GAP_MM / s
    assert r.y >= bottom_edge + 4.5 or r.y + r.h - 1 <= top_edge - 4.5
    sdown = (struct_mm[0] - struct_mm) / s
    assert r.y + sdown.min() >= 0 and r.y + r.h - 1 + sdown.max() <= img["height_px"] - 1
    assert 0 <= r.x and r.x + r.w <= img["width_px"]


@pytest.mark.parametrize("name", list(CASES))
def test_analysis_from_the_proposed_rig_equals_the_true_rigs(cases, name):
    # The same frames, analysed with the true rig and with the proposed one (its scale off by eps, the error
    # measured above; its ROIs elsewhere on the ball and plate). Same impacts on the same plates. Impact
    # times: the same crossings of the same parabolas, within 0.05 frame. COR: the ratio of two velocity
    # differences would not change if all positions scale alike; the analysis is not exactly scale-free
    # though: with ONLY mm_per_px changed by eps = +0.35 % (ROIs kept) the top impacts' COR moved by
    # +3.5e-4, i.e. ~0.1 eps (the identification mixes in mm constants of the rig). Allowed: the DIC noise
    # of other subsets (4 of the two analyses' combined sigma) plus 0.2 |eps|.
    c = cases[name]
    true, prop = c["runs"]["true"], c["runs"]["proposed"]
    eps = abs(load_rig(c["rec"] / "rig.yaml").camera.mm_per_px / c["truth"]["image"]["mm_per_px"] - 1.0)
    assert true["t"].size == prop["t"].size >= 8
    assert list(true["plate"]) == list(prop["plate"])
    dt_frames = np.abs(true["t"] - prop["t"]) * FPS
    dcor = np.abs(true["cor"] - prop["cor"])
    tol = 4.0 * np.hypot(true["cor_std"], prop["cor_std"]) + 0.2 * eps
    print(f"{name}: {true['t'].size} impacts, max |dt| {dt_frames.max():.4f} frame, max |dCOR| {dcor.max():.2e} "
          f"(max allowed {tol.min():.2e}..{tol.max():.2e})")
    assert dt_frames.max() <= 0.05
    assert np.all(dcor <= tol)


def test_preview_shows_frame0_twice_as_large(cases):
    c = cases["fine_scale"]
    preview = cv2.imread(str(c["rec"] / "rig_preview.png"))
    frame0 = read_image(sorted((c["rec"] / "frames").iterdir())[0])
    assert preview is not None and preview.shape[:2] == (2 * frame0.shape[0], 2 * frame0.shape[1])
    # drawn on: ROIs in colour (frame 0 is gray)
    assert np.any(np.ptp(preview.astype(int), axis=2) > 100)


def test_camera_file_gives_the_same_rig_without_fps(cases, tmp_path, capsys):
    # the lab path: an MRAW (header holds the frame rate) instead of PNG frames; the same pixels give the
    # same proposal, and --fps is not needed
    c = cases["fine_scale"]
    images = np.stack([read_image(p) for p in sorted((c["rec"] / "frames").iterdir())])
    mraw_dir = tmp_path / "mraw"
    mraw_dir.mkdir()
    write_mraw(images, mraw_dir / "video.cih", 8, FPS)
    assert main(["init", str(mraw_dir), "--ball-diameter-mm", "4.77", "--gap-mm", str(GAP_MM)]) == 0
    ours = yaml.safe_load((mraw_dir / "rig.yaml").read_text())
    png = yaml.safe_load((c["rec"] / "rig.yaml").read_text())
    assert ours == png


def _frames_copy(src: Path, dst: Path, n: int, edit=None) -> Path:
    (dst / "frames").mkdir(parents=True)
    for p in sorted((src / "frames").iterdir())[:n]:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(dst / "frames" / p.name), edit(img) if edit else img)
    return dst


def _refused(capsys, args: list[str]) -> str:
    code = main(args)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_refuses_a_gap_that_contradicts_the_ball(cases, tmp_path, capsys):
    rec = cases["fine_scale"]["rec"]
    # the true gap is 16.6 mm: 10 % more is far beyond what the localisation allows (a few tenths of a %)
    err = _refused(capsys, ["init", str(rec), "--ball-diameter-mm", "4.77", "--gap-mm", "18.26", "--fps", "1000",
                            "--out", str(tmp_path / "wrong.yaml")])
    assert "disagree" in err
    assert not (tmp_path / "wrong.yaml").exists()


def test_refuses_frames_without_a_ball(cases, tmp_path, capsys):
    rec = _frames_copy(cases["fine_scale"]["rec"], tmp_path / "noball", 3, lambda img: np.full_like(img, 90))
    err = _refused(capsys, ["init", str(rec), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6", "--fps", "1000"])
    assert "no ball found" in err and not (rec / "rig.yaml").exists()


def test_refuses_when_no_structure_patch_fits(cases, tmp_path, capsys):
    # the plates cropped to a 12 px band beyond their edges: too little plate for a 31 px subset
    c = cases["fine_scale"]
    img, st = c["truth"]["image"], c["truth"]["frames"]["structure_mm"][0]
    top = img["row_mid"] - st / img["mm_per_px"] - 0.5 * GAP_MM / img["mm_per_px"]
    lo, hi = int(top) - 12, int(top + GAP_MM / img["mm_per_px"]) + 13
    rec = _frames_copy(c["rec"], tmp_path / "cropped", 80, lambda im: im[lo:hi].copy())
    err = _refused(capsys, ["init", str(rec), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6", "--fps", "1000"])
    assert "no textured patch of the structure" in err


def test_refuses_unreadable_input_and_a_missing_frame_rate(cases, tmp_path, capsys):
    rec = _frames_copy(cases["fine_scale"]["rec"], tmp_path / "corrupt", 5)
    first = sorted((rec / "frames").iterdir())[0]
    first.write_bytes(b"not a png")
    err = _refused(capsys, ["init", str(rec), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6", "--fps", "1000"])
    assert first.name in err
    err = _refused(capsys, ["init", str(tmp_path / "nowhere"), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6",
                            "--fps", "1000"])
    assert "nowhere" in err
    # PNG frames carry no frame rate: --fps is required, and said so
    err = _refused(capsys, ["init", str(cases["fine_scale"]["rec"]), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6",
                            "--out", str(tmp_path / "x.yaml")])
    assert "--fps" in err
