"""In-plane rigid rotation of a DIC mesh from its subsets' translations.

Convention: image axes x = column (right), y = row (DOWN); an angle is positive
COUNTER-CLOCKWISE as the camera sees the image. A rotation by a small angle theta about
the mesh centroid moves a point at (x, y) (relative to the centroid) by
theta * (y, -x) px (to first order; the 2-D Procrustes angle differs by theta^3 / 6,
2e-5 rad at 0.05 rad, far below the noise).

Why not the subsets' own rotation: the tracker's IC-GN has a translation-only shape function
(:mod:`vibro_dic.icgn`), so each subset reports one displacement. Its translation Gauss-Newton
solution in a linearly varying displacement field v(x) is, to first order,

    u_i = H_i^-1 sum_j J_j J_j^T v(x_j),    J_j = grad f at pixel j,  H_i = sum_j J_j J_j^T,

the field at the subset's gradient-weighted centre, not at its geometric centre: with 31 px
subsets of random speckle that centre is off by ~1 px, a 10-20 % error on a lever arm of
~7 px (a 2 x 2 mesh of 31 px subsets 10 px apart). :func:`rotation_lever_arms` computes the
exact first-order lever arm a_i = H_i^-1 sum_j J_j J_j^T (y_j, -x_j) from the reference
image, so u_i = t + theta a_i, and :func:`vibro_dic.kernels.combine_points` solves that for
(t, theta) by least squares over the kept points.

Noise: with per-point displacement noise sigma_u (px, per component) the angle's 1-sigma is
sigma_u / sqrt(sum |a_i - mean a|^2) (about sigma_u / (mesh radius x sqrt(N))); sigma_u is
estimated from the residuals about the rigid fit with 2N - 3 degrees of freedom.
"""

from __future__ import annotations

import numpy as np

from .icgn import IcgnBlocks

MIN_ARM_SPREAD_PX2 = 1.0  # sum |a_i - mean|^2 below this: the points cannot show a rotation


def rotation_lever_arms(subsets: IcgnBlocks, centres_px: np.ndarray, subset_px: int, *,
                        corrected: bool = True) -> np.ndarray:
    """(N, 2) px per rad: what each subset's translation estimate moves per radian of rotation
    about the centroid of ``centres_px`` (see module doc). ``corrected=False`` gives the geometric
    arms (y_i, -x_i) of the subset centres (what a naive fit uses)."""
    centres = np.asarray(centres_px, dtype=float)
    centroid = centres.mean(axis=0)
    rel = centres - centroid
    if not corrected:
        return np.column_stack([rel[:, 1], -rel[:, 0]])
    h = subset_px // 2
    rows, cols = np.mgrid[-h:h + 1, -h:h + 1]
    px = rel[:, 0:1] + cols.ravel()[None, :]  # (N, P) pixel x relative to the centroid
    py = rel[:, 1:2] + rows.ravel()[None, :]
    fx = subsets.fx.astype(np.float64)
    fy = subsets.fy.astype(np.float64)
    proj = fx * py - fy * px  # J . v per radian, v = (y, -x)
    bx = np.einsum("ij,ij->i", fx, proj)
    by = np.einsum("ij,ij->i", fy, proj)
    arms = np.column_stack([subsets.ixx * bx + subsets.ixy * by, subsets.ixy * bx + subsets.iyy * by])
    # an untextured subset has no meaningful inverse Hessian: fall back to its geometric arm
    geo = np.column_stack([rel[:, 1], -rel[:, 0]])
    return np.where(subsets.textured[:, None], arms, geo)


def effective_centres(subsets: IcgnBlocks, centres_px: np.ndarray, subset_px: int) -> np.ndarray:
    """(N, 2) px: where each subset's translation estimate samples a smoothly varying displacement field, its
    gradient-weighted centre c_i = p_i + H_i^-1 sum_j J_j J_j^T d_j (d_j a pixel's offset from the geometric centre
    p_i; module doc): u_i = v(c_i) to first order for an isotropic gradient of the field (a lens's magnification
    changing across the image), not v(p_i). ~1 px off p_i for 31 px subsets of random speckle; p_i for an
    untextured subset."""
    centres = np.asarray(centres_px, dtype=float)
    h = subset_px // 2
    rows, cols = np.mgrid[-h:h + 1, -h:h + 1]
    dx, dy = cols.ravel()[None, :].astype(float), rows.ravel()[None, :].astype(float)
    fx = subsets.fx.astype(np.float64)
    fy = subsets.fy.astype(np.float64)
    proj = fx * dx + fy * dy                 # J . d per pixel
    bx = np.einsum("ij,ij->i", fx, proj)
    by = np.einsum("ij,ij->i", fy, proj)
    offset = np.column_stack([subsets.ixx * bx + subsets.ixy * by, subsets.ixy * bx + subsets.iyy * by])
    return centres + np.where(subsets.textured[:, None], offset, 0.0)
