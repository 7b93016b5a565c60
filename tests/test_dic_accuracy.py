"""Sub-pixel accuracy of the DIC tracker: synthetic speckle with exact shifts, and real images
with externally imposed shifts (../shared/validation/dic_rigid_shift)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from vibro_dic.noise import cramer_rao_px
from vibro_dic.speckle import add_noise, speckle_pattern
from vibro_dic.tracker import DicTracker
from vibro_io.frames import read_image
from vibro_io.rig import DicConfig, Roi

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
RIGID = SHARED / "validation" / "dic_rigid_shift"

SHAPE = (160, 480)
# paper-like meshes: ball 61x61 px (16 points), structure 81x61 px (24 points), 31 px subsets
CFG = DicConfig(31, 10, Roi(330, 50, 61, 61), Roi(80, 50, 81, 61))
SHIFTS = np.round(np.arange(0.0, 1.0 + 1e-9, 0.05), 2)  # 0 .. 1 px in 0.05 px steps
NOISE = 2.0  # gray levels
# the images are rounded to uint8, which adds uniform quantisation noise of variance 1/12
NOISE_EFF = math.sqrt(NOISE**2 + 1.0 / 12.0)


def _shift_errors(method: str, axis: str, reps: int) -> tuple[np.ndarray, np.ndarray, list[DicTracker]]:
    """Mesh errors (reps, shifts, 2 meshes) and per-point ball errors (reps, shifts, 16) in px."""
    mesh_err = np.zeros((reps, SHIFTS.size, 2))
    point_err = np.zeros((reps, SHIFTS.size, 16))
    trackers = []
    for rep in range(reps):
        pat = speckle_pattern(SHAPE, seed=10 + rep)
        rng = np.random.default_rng(100 + rep)
        ref = add_noise(pat.render(), NOISE, rng)
        tr = DicTracker(ref, CFG, 1.0, method=method)
        trackers.append(tr)
        for i, d in enumerate(SHIFTS):
            # up by d px is row shift -d; "x" shifts along columns
            dx, dy = (0.0, -d) if axis == "y" else (d, 0.0)
            img = add_noise(pat.render(dx, dy), NOISE, rng)
            tr.ball.history.clear()  # each image is an independent pair with frame 0
            tr.structure.history.clear()
            row = tr.track_image(i, 0.0, img)
            assert not row.lost and row.ball_valid >= 14 and row.structure_valid >= 22
            for j, name in enumerate(("ball", "structure")):
                res = tr.last_results[name]
                got = -res.u_px[1] if axis == "y" else res.u_px[0]
                mesh_err[rep, i, j] = got - d
            pu = tr.last_results["ball"].point_u_px
            point_err[rep, i] = (-pu[:, 1] if axis == "y" else pu[:, 0]) - d
            # the mm output is the same number, scaled (mm_per_px = 1 here) and positive up
            if axis == "y":
                assert row.ball_mm == pytest.approx(-tr.last_results["ball"].u_px[1], abs=1e-9)
    return mesh_err, point_err, trackers


@pytest.mark.parametrize("axis", ["y", "x"])
def test_icgn_bias_and_rms_within_0p01_px_per_mesh(axis: str) -> None:
    err, _, _ = _shift_errors("icgn", axis, reps=3 if axis == "y" else 1)
    bias = err.mean(axis=0)  # per shift and mesh, averaged over noise realisations
    rms = np.sqrt((err**2).mean(axis=(0, 1)))
    # goal of the issue: bias and RMS <= 0.01 px per mesh
    assert np.abs(bias).max() <= 0.01, bias
    assert rms.max() <= 0.01, rms


def test_icgn_beats_parabolic_peak_fit_and_sits_near_the_cramer_rao_bound() -> None:
    icgn, points, trackers = _shift_errors("icgn", "y", reps=2)
    para, _, _ = _shift_errors("parabolic", "y", reps=2)
    rms_icgn = np.sqrt((icgn**2).mean())
    rms_para = np.sqrt((para**2).mean())
    # the parabola's peak-locking S-curve (systematic, ~0.01 px) is the error IC-GN removes
    assert rms_icgn < rms_para
    # Cramer-Rao-type bound per subset: sqrt(2) sigma / sqrt(sum grad_y^2). IC-GN is an
    # (asymptotically) efficient estimator, so per-point RMS errors should sit close to it:
    # not below it by more than the sampling scatter (~10 % with ~670 samples) and not
    # above 1.6x (the remaining interpolation bias is a few 1e-3 px).
    crb = np.concatenate([cramer_rao_px(t.ball.subsets.grad_sq[:, 1], NOISE_EFF) for t in trackers])
    per_point_rms = np.sqrt((points**2).mean(axis=1)).ravel()
    ratio = per_point_rms.mean() / crb.mean()
    assert 0.8 <= ratio <= 1.6, ratio


def test_six_tap_interpolant_has_less_bias_than_bicubic() -> None:
    # noise-free images: what is left is the interpolation bias (S-curve over the shift)
    pat = speckle_pattern(SHAPE, seed=10)
    ref = pat.render()
    worst = {}
    for taps in (4, 6):
        tr = DicTracker(ref, CFG, 1.0, taps=taps)
        err = []
        for d in SHIFTS:
            tr.ball.history.clear()
            tr.structure.history.clear()
            row = tr.track_image(0, 0.0, pat.render(0.0, -d))
            err += [row.ball_mm - d, row.structure_mm - d]
        worst[taps] = np.abs(err).max()
    # Keys' 6-point kernel is 4th-order accurate vs 3rd for bicubic a = -0.5: its bias on a
    # pattern with little energy near Nyquist is several times smaller; 0.005 px is half the goal
    assert worst[6] <= 0.005
    assert worst[6] < 0.5 * worst[4]


def _rigid_series(folder: str, prefix: str) -> list[np.ndarray]:
    d = RIGID / folder
    if not d.is_dir():
        pytest.fail(f"validation images missing: {d}")
    # transpose: the imposed shift of -k/10 px in columns becomes -k/10 px in rows = +k/10 px UP
    return [np.ascontiguousarray(read_image(d / f"{prefix}{k}.tiff").T) for k in range(11)]


def test_shift_table_is_what_we_assume() -> None:
    with (RIGID / "shifts.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    hc = [r for r in rows if r["file"].startswith("reu_hc")]
    for r in hc:
        k = int(Path(r["file"]).stem.rsplit("_", 1)[1])
        assert float(r["shift_x_px"]) == pytest.approx(-k / 10) and float(r["shift_y_px"]) == 0.0


@pytest.mark.parametrize("folder,prefix", [("reu_hc_upsample_10_rigid_pixel_shift", "hc_dic_"),
                                           ("reu_lc_upsample_10_rigid_pixel_shift", "lc_dic_reu_")])
def test_real_images_with_imposed_shifts(folder: str, prefix: str) -> None:
    images = _rigid_series(folder, prefix)
    # transposed images are 487 rows x 325 columns; ROIs in the central part, far from the
    # edge that the generating script zero-filled (now the bottom rows)
    cfg = DicConfig(31, 10, Roi(120, 130, 61, 61), Roi(200, 250, 81, 61))
    tr = DicTracker(images[0], cfg, 1.0)
    para = DicTracker(images[0], cfg, 1.0, method="parabolic")
    err, err_para = [], []
    for k, img in enumerate(images):
        row = tr.track_image(k, 0.0, img)
        assert not row.lost
        err.append([row.ball_mm - k / 10, row.structure_mm - k / 10])
        # the imposed shift is along one axis only: the other component must stay ~0
        assert abs(tr.last_results["ball"].u_px[0]) < 0.003
        prow = para.track_image(k, 0.0, img)
        err_para.append([prow.ball_mm - k / 10, prow.structure_mm - k / 10])
    err = np.array(err)
    # Tolerance 0.015 px per image: the images are linear-interpolation shifts (a shift plus a
    # slight blur), whose known bias is the S-curve of +-0.011 px that the independent cubic
    # SSD estimator of the README also shows; the images share one noise realisation, so the
    # random part is < 0.002 px; 0.015 = 0.011 + margin for our interpolant's own bias.
    assert np.abs(err).max() <= 0.015, err
    # the S-curve vanishes at 0, 0.5 and 1 px (the blur is symmetric there)
    assert np.abs(err[[0, 5, 10]]).max() <= 0.003, err[[0, 5, 10]]
    # and IC-GN beats the parabolic baseline on them
    assert np.sqrt((err**2).mean()) < np.sqrt((np.array(err_para) ** 2).mean())
