"""Mesh placement, the synthetic speckle helper, interpolation weights and the IC-GN step
(vibro_dic.mesh, vibro_dic.speckle, vibro_dic.interp, vibro_dic.icgn)."""

from __future__ import annotations

import numpy as np
import pytest

from vibro_dic.icgn import IcgnBlocks
from vibro_dic.interp import kernel_weights, kernel_weights_one, sample_blocks
from vibro_dic.mesh import mesh_points
from vibro_dic.speckle import speckle_pattern
from vibro_io.rig import Roi
from vibro_model.errors import RecordingError


@pytest.mark.parametrize("roi,subset,step", [(Roi(10, 20, 61, 61), 31, 10), (Roi(0, 0, 100, 45), 21, 7),
                                            (Roi(5, 7, 31, 31), 31, 10), (Roi(3, 4, 90, 200), 15, 13)])
def test_every_subset_inside_roi_and_grid_pitch(roi: Roi, subset: int, step: int) -> None:
    pts = mesh_points(roi, subset, step)
    h = subset // 2
    assert pts.shape[1] == 2 and len(pts) >= 1
    assert np.all(pts[:, 0] - h >= roi.x) and np.all(pts[:, 0] + h <= roi.x + roi.w - 1)
    assert np.all(pts[:, 1] - h >= roi.y) and np.all(pts[:, 1] + h <= roi.y + roi.h - 1)
    # the grid is as dense as the step allows: one more column/row would not fit
    nx = len(np.unique(pts[:, 0]))
    ny = len(np.unique(pts[:, 1]))
    assert nx == (roi.w - subset) // step + 1 and ny == (roi.h - subset) // step + 1
    if nx > 1:
        assert np.allclose(np.diff(np.unique(pts[:, 0])), step)


def test_paper_like_meshes_hold_40_points() -> None:
    assert len(mesh_points(Roi(0, 0, 61, 61), 31, 10)) + len(mesh_points(Roi(0, 0, 81, 61), 31, 10)) == 40


@pytest.mark.parametrize("roi,subset,step,what", [(Roi(0, 0, 30, 60), 31, 10, "smaller"),
                                                 (Roi(0, 0, 60, 60), 30, 10, "odd"),
                                                 (Roi(0, 0, 60, 60), 31, 0, "mesh_step_px")])
def test_bad_mesh_parameters_are_refused(roi: Roi, subset: int, step: int, what: str) -> None:
    with pytest.raises(RecordingError, match=what):
        mesh_points(roi, subset, step)


def test_speckle_shift_is_exact_for_whole_pixels_and_consistent_for_fractions() -> None:
    pat = speckle_pattern((64, 96), seed=4)
    ref = pat.render()
    # an integer Fourier shift of a periodic pattern is exactly np.roll (float rounding only)
    assert np.allclose(pat.render(3.0, -2.0), np.roll(ref, (-2, 3), axis=(0, 1)), atol=1e-9)
    # shifting by 0.3 then by 0.45 equals shifting by 0.75 (composition of exact shifts)
    two = speckle_pattern((64, 96), seed=4)
    two.spectrum = np.fft.rfft2(pat.render(0.3, 0.1))
    assert np.allclose(two.render(0.45, 0.2), pat.render(0.75, 0.3), atol=1e-9)
    # statistics requested
    assert abs(ref.mean() - 128.0) < 1e-9 and abs(ref.std() - 45.0) < 1e-6


@pytest.mark.parametrize("taps", [4, 6])
def test_interpolation_reproduces_polynomials(taps: int) -> None:
    # Keys kernels sum to 1 and reproduce linear functions exactly (a = -0.5 and the
    # six-point kernel are both at least second-order), so a ramp is sampled exactly.
    t = np.linspace(0.0, 0.99, 12)
    w = kernel_weights(t, taps)
    offs = np.arange(taps) - (taps // 2 - 1)
    assert np.allclose(w.sum(axis=1), 1.0, atol=1e-6)
    assert np.allclose((w * offs).sum(axis=1), t, atol=1e-6)
    yy, xx = np.mgrid[0:40, 0:50].astype(np.float32)
    ramp = 0.7 * xx - 0.4 * yy
    x0 = np.array([10.25, 20.5, 5.9])
    y0 = np.array([8.75, 3.1, 12.0])
    got = sample_blocks(ramp, x0, y0, (5, 7), taps)
    want = 0.7 * (x0[:, None, None] + np.arange(7)) - 0.4 * (y0[:, None, None] + np.arange(5)[:, None])
    assert np.allclose(got, want, atol=1e-4)


@pytest.mark.parametrize("taps", [4, 6])
def test_one_offset_weights_equal_the_batched_ones(taps: int) -> None:
    # the per-frame one-block path writes each tap's weight as a cubic in t: the same polynomials
    t = np.linspace(0.0, 0.999, 41)
    want = kernel_weights(t, taps)
    got = np.array([kernel_weights_one(float(x), taps) for x in t])
    assert np.allclose(got, want, rtol=0, atol=4 * np.finfo(np.float32).eps)


def _znssd_gauss_newton_step(blocks: IcgnBlocks, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The IC-GN translation step from its definition (module doc of vibro_dic.icgn), in float64:
    e = f~ - (df/dg) g~, du = H^-1 sum J e with J = (fx, fy); and the ZNCC f~.g~ / (df dg)."""
    g = g.reshape(len(g), -1).astype(np.float64)
    gt = g - g.mean(axis=1, keepdims=True)
    ft, fx, fy = (a.astype(np.float64) for a in (blocks.f_tilde, blocks.fx, blocks.fy))
    df, dg = np.linalg.norm(ft, axis=1), np.linalg.norm(gt, axis=1)
    e = ft - (df / dg)[:, None] * gt
    du = []
    for i in range(len(g)):
        h = np.array([[fx[i] @ fx[i], fx[i] @ fy[i]], [fx[i] @ fy[i], fy[i] @ fy[i]]])
        du.append(np.linalg.solve(h, [fx[i] @ e[i], fy[i] @ e[i]]))
    return np.array(du), np.einsum("ij,ij->i", ft, gt) / (df * dg)


def test_icgn_step_is_the_gauss_newton_step_of_the_znssd() -> None:
    # the step is computed from a few precomputed sums (one product with g); it must be the textbook step
    pat = speckle_pattern((90, 120), seed=6)
    ref = pat.render().astype(np.float32)
    cur = (1.1 * pat.render(0.37, -0.21) + 7.0).astype(np.float32)  # shifted, with a gain and an offset
    corners = np.array([[20, 15], [52, 40], [70, 20]])
    blocks = IcgnBlocks(ref, corners, (21, 21))
    g = blocks.sample(cur, np.zeros((3, 2)))
    du, zncc, ok = blocks.step(g)
    want_du, want_zncc = _znssd_gauss_newton_step(blocks, g)
    assert ok.all()
    assert np.allclose(du, want_du, rtol=0, atol=1e-9)
    assert np.allclose(zncc, want_zncc, rtol=0, atol=1e-12)
    # the step moves towards the true shift (0.37, -0.21) px: Gauss-Newton from 0.4 px off lands within 0.05 px
    assert np.all(np.abs(du - [0.37, -0.21]) < 0.05)


def test_a_subset_measures_a_magnified_field_at_its_gradient_weighted_centre() -> None:
    """A lens's magnification changes across the image: the displacement field then has a gradient over a subset,
    and the translation IC-GN measures it at the subset's gradient-weighted centre
    (vibro_dic.rotation.effective_centres), ~1 px from the geometric centre, not at the centre. The tracker's lens
    correction undistorts those centres (tracker step 8). Field: an isotropic magnification by 1 + s about o."""
    from scipy.ndimage import map_coordinates

    from vibro_dic.rotation import effective_centres

    ref = speckle_pattern((240, 240), seed=3).render()
    s, o = 0.02, np.array([20.0, 30.0])          # (x, y) px
    rows, cols = np.mgrid[0:240, 0:240].astype(float)
    src_x, src_y = o[0] + (cols - o[0]) / (1 + s), o[1] + (rows - o[1]) / (1 + s)
    cur = map_coordinates(ref.astype(float), [src_y, src_x], order=5, mode="nearest").astype(np.float32)
    subset = 31
    centres = mesh_points(Roi(60, 60, 120, 120), subset, 10).astype(float)
    blocks = IcgnBlocks(ref, centres - subset // 2, (subset, subset), max_iter=30, tol_px=1e-4)
    res = blocks.refine(cur, s * (centres - o))
    ok = res.converged & blocks.textured
    assert ok.sum() > 50
    eff = effective_centres(blocks, centres, subset)
    err_geometric = np.linalg.norm(res.u - s * (centres - o), axis=1)[ok]
    err_effective = np.linalg.norm(res.u - s * (eff - o), axis=1)[ok]
    assert np.median(np.linalg.norm(eff - centres, axis=1)[ok]) > 0.3     # the offsets matter: ~s x 1 px
    assert np.median(err_effective) < 0.25 * np.median(err_geometric)
