"""The tracker's compiled per-frame kernels (vibro_dic.kernels) against their definitions: sampling against the
OpenCV separable filter of vibro_dic.interp, the subsets' step against the textbook ZNSSD Gauss-Newton step,
the box's IC-GN against an exactly shifted speckle image (Fourier shift, band-limited), and the points' rigid
fit against least squares on the points kept."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from vibro_dic import kernels
from vibro_dic.icgn import IcgnBlocks
from vibro_dic.interp import CUBIC_IN_T, sample_block
from vibro_dic.speckle import speckle_pattern

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_dic_mesh import _znssd_gauss_newton_step  # noqa: E402

SHIFT = (0.37, -0.21)  # px (x, y), imposed on the speckle


@pytest.fixture(scope="module")
def images() -> tuple[np.ndarray, np.ndarray]:
    """A band-limited speckle (reference) and the same pattern shifted by SHIFT, exactly (Fourier)."""
    pat = speckle_pattern((90, 160), seed=6)
    return pat.render().astype(np.float32), pat.render(*SHIFT).astype(np.float32)


@pytest.mark.parametrize("taps", [4, 6])
def test_sampling_equals_the_separable_filter(images, taps: int) -> None:
    ref, _ = images
    rng = np.random.default_rng(taps)
    h, w = 23, 57
    for x0, y0 in rng.uniform([8, 8], [90, 50], size=(20, 2)):
        tmp = np.empty((h + taps - 1, w), dtype=np.float32)
        out = np.empty((h, w), dtype=np.float32)
        kernels.sample_block(ref, float(x0), float(y0), np.ascontiguousarray(CUBIC_IN_T[taps]), tmp, out)
        want = sample_block(ref, float(x0), float(y0), (h, w), taps)
        # both in float32 over gray levels ~0-255: rounding differs by a few ulp of 255
        assert np.max(np.abs(out - want)) < 32 * 255 * np.finfo(np.float32).eps


def test_subset_steps_are_the_textbook_gauss_newton_steps(images) -> None:
    ref, cur = images
    cur = 1.1 * cur + 7.0  # a gain and an offset: the ZNSSD ignores both
    box_corner = np.array([20, 15])
    offsets = np.array([[0, 0], [10, 4], [30, 20], [41, 27]])
    subsets = IcgnBlocks(ref, box_corner + offsets, (21, 21))
    g_box = cur[15:15 + 48, 20:20 + 62].astype(np.float32)  # the box sampled at u = 0
    m = len(offsets)
    du, zncc, ok = np.empty((m, 2)), np.empty(m), np.empty(m, dtype=bool)
    kernels.subset_steps(g_box, offsets, np.ascontiguousarray(subsets._proj), subsets.df, subsets._du_f, du, zncc, ok)
    g = np.stack([g_box[y:y + 21, x:x + 21] for x, y in offsets])
    want_du, want_zncc = _znssd_gauss_newton_step(subsets, g)
    assert ok.all()
    assert np.allclose(du, want_du, rtol=0, atol=1e-9) and np.allclose(zncc, want_zncc, rtol=0, atol=1e-12)
    # a flat window has no texture: no step, no ZNCC
    flat = g_box.copy()
    flat[0:21, 0:21] = 100.0
    kernels.subset_steps(flat, offsets, np.ascontiguousarray(subsets._proj), subsets.df, subsets._du_f, du, zncc, ok)
    assert not ok[0] and math.isnan(zncc[0]) and np.array_equal(du[0], [0.0, 0.0]) and ok[1:].all()


def _refine(block: IcgnBlocks, image: np.ndarray, u0: tuple[float, float], *, max_move_px: float = 2.0,
            max_iter: int = 10, tol_px: float = 0.005) -> tuple[int, float, float, float, np.ndarray]:
    h, w = block.size
    g = np.empty((h, w), dtype=np.float32)
    tmp = np.empty((h + 5, w), dtype=np.float32)
    df, du_fx, du_fy = block._one
    code, ux, uy, zncc = kernels.refine_box(image, float(block.corners[0, 0]), float(block.corners[0, 1]), u0[0],
                                            u0[1], np.ascontiguousarray(block._proj[0]), df, du_fx, du_fy,
                                            np.ascontiguousarray(CUBIC_IN_T[6]), max_move_px, max_iter, tol_px, g, tmp)
    return code, ux, uy, zncc, g


def test_box_refinement_finds_the_imposed_shift(images) -> None:
    ref, cur = images
    box = IcgnBlocks(ref, np.array([[30, 20]]), (41, 91))
    for start in [(0.0, 0.0), (1.2, -0.9), (-0.5, 0.6)]:
        code, ux, uy, zncc, g = _refine(box, cur, start)
        assert code == kernels.CONVERGED
        # interpolation bias of the 6-tap kernel on this speckle (blur 1.5 px) is below 0.0024 px
        # (interp module doc); the last step is below tol 0.005 px, its error O(step^2)
        assert abs(ux - SHIFT[0]) < 0.005 and abs(uy - SHIFT[1]) < 0.005, (start, ux, uy)
        assert zncc > 0.999
        # the samples returned are the box at the u returned
        assert np.max(np.abs(g - sample_block(cur, 30 + ux, 20 + uy, (41, 91), 6))) < 1e-2
        # the vectorised numpy IC-GN of the same block agrees to its last step (below tol: numpy adds that step,
        # the kernel returns the u its samples were taken at)
        res = IcgnBlocks(ref, np.array([[30, 20]]), (41, 91), tol_px=0.005).refine(cur, np.array([start]))
        assert res.converged[0] and np.hypot(*(res.u[0] - [ux, uy])) <= 0.005 + 1e-6


def test_box_refinement_says_why_it_stopped(images) -> None:
    ref, cur = images
    box = IcgnBlocks(ref, np.array([[30, 20]]), (41, 91))
    assert _refine(box, cur, (0.0, 0.0), max_move_px=0.1)[0] == kernels.MOVED_TOO_FAR  # the shift is 0.37 px
    assert _refine(box, cur, (-29.0, 0.0))[0] == kernels.LEFT_IMAGE  # support beyond column 0
    assert _refine(box, cur, (0.0, 0.0), max_iter=1)[0] == kernels.NOT_CONVERGED
    flat = np.full_like(cur, 90.0)
    assert _refine(box, flat, (0.0, 0.0))[0] == kernels.NO_TEXTURE


def _combine(u, zncc, conv, arms, **kw):
    valid = np.empty(len(u), dtype=bool)
    args = dict(zncc_min=0.6, outlier_k=3.0, outlier_floor_px=0.1, min_arm_spread_px2=1.0) | kw
    out = kernels.combine_points(np.asarray(u, float), np.asarray(zncc, float), np.asarray(conv, bool),
                                 args["zncc_min"], args["outlier_k"], args["outlier_floor_px"],
                                 np.asarray(arms, float), args["min_arm_spread_px2"], valid)
    return out, valid


def test_points_combine_to_the_least_squares_rigid_motion() -> None:
    rng = np.random.default_rng(3)
    n = 24
    arms = rng.uniform(-12, 12, size=(n, 2))
    t, theta, sigma = np.array([0.8, -3.1]), 0.004, 0.01
    u = t + theta * arms + rng.normal(0, sigma, size=(n, 2))
    zncc = np.full(n, 0.98)
    conv = np.ones(n, dtype=bool)
    u[3] += [2.0, 0.0]        # an outlier, 200 sigma off
    u[5] = np.nan             # a point lost
    zncc[7] = 0.3             # a point below zncc_min
    conv[9] = False           # a point that did not converge
    (kept, mx, my, zm, th, th_std, sig, ax, ay), valid = _combine(u, zncc, conv, arms)
    expect = np.ones(n, dtype=bool)
    expect[[3, 5, 7, 9]] = False
    assert np.array_equal(valid, expect) and kept == n - 4
    # least squares of u_i = t + theta a_i over the kept points
    a = arms[valid]
    rows = np.zeros((2 * kept, 3))
    rows[0::2, 0], rows[1::2, 1] = 1.0, 1.0
    rows[0::2, 2], rows[1::2, 2] = a[:, 0], a[:, 1]
    sol, res, *_ = np.linalg.lstsq(rows, u[valid].reshape(-1), rcond=None)
    assert th == pytest.approx(sol[2], rel=1e-9)
    assert (mx, my) == pytest.approx(tuple(sol[:2] + sol[2] * a.mean(axis=0)), rel=1e-9)  # the points' mean
    assert (ax, ay) == pytest.approx(tuple(a.mean(axis=0)), rel=1e-12)
    assert sig == pytest.approx(math.sqrt(res[0] / (2 * kept - 3)), rel=1e-9)
    assert zm == pytest.approx(0.98)
    # the fit recovers the imposed motion within its own sigma (3 sigma)
    assert abs(th - theta) < 3 * th_std and abs(sig - sigma) < 0.3 * sigma


def test_points_too_few_for_a_rotation() -> None:
    (kept, mx, my, *_rest), valid = _combine([[0.5, 1.0], [np.nan, 0.0]], [0.9, 0.9], [True, True],
                                             [[1.0, 0.0], [0.0, 1.0]])
    th = _rest[1]
    assert kept == 1 and (mx, my) == (0.5, 1.0) and math.isnan(th) and valid.tolist() == [True, False]
    (kept, *_), valid = _combine([[np.nan, np.nan]] * 3, [0.9] * 3, [True] * 3, [[0.0, 0.0]] * 3)
    assert kept == 0 and not valid.any()
