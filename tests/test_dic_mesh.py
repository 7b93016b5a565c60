"""Mesh placement and the synthetic speckle helper (vibro_dic.mesh, vibro_dic.speckle)."""

from __future__ import annotations

import numpy as np
import pytest

from vibro_dic.interp import kernel_weights, sample_blocks
from vibro_dic.mesh import mesh_points
from vibro_dic.speckle import speckle_pattern
from vibro_io.errors import RecordingError
from vibro_io.rig import Roi


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
