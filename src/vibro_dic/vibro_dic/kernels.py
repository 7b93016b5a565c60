"""Compiled per-frame kernels of the mesh tracker (numba): one call per mesh and step, no numpy call per pixel.

A mesh of the live tracker is small (the ball: 4 subsets of 31 px in a 41 x 41 box; the structure: 24 in
41 x 141), so with numpy each frame's work was mostly the cost of ~100 small array calls, not arithmetic
(bench/bench_dic_ab.py measures the two against each other). The kernels do the same arithmetic as
:class:`vibro_dic.icgn.IcgnBlocks` (translation IC-GN, ZNSSD) and :mod:`vibro_dic.rotation`:

- :func:`refine_box`: IC-GN of one block (a mesh's bounding box) to a step below ``tol_px``, sampling the
  image with the separable Keys kernel of :mod:`vibro_dic.interp` (weights as cubics in the fractional offset);
- :func:`subset_steps`: one Gauss-Newton step of every subset from the box's samples (the subsets are windows of
  the box);
- :func:`combine_points`: the mesh's displacement from its points: valid points (converged, ZNCC, finite),
  outliers beyond ``outlier_k`` robust sigmas (median and MAD per axis) dropped, then the rigid fit
  u_i = t + theta a_i (:mod:`vibro_dic.rotation`: the lever arms a_i and the noise model).

Conventions as in :mod:`vibro_dic.icgn`: displacements (x, y) px, x = column, y = row; images 2-D float32.
Compiled once per machine (``cache=True``: numba keeps the machine code beside this file).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: fastmath flags that let sums be reordered (SIMD) but keep NaN and infinity semantics (a lost point is NaN)
_REORDER = {"reassoc", "contract", "nsz", "arcp"}
#: refine_box's outcome codes
CONVERGED, LEFT_IMAGE, MOVED_TOO_FAR, NO_TEXTURE, NOT_CONVERGED = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True, fastmath=_REORDER)
def _weights(t: float, cubic: np.ndarray, out: np.ndarray) -> None:
    """Kernel weights of fractional offset t in [0, 1): ``cubic`` (taps, 4) is each tap's weight as a cubic in t."""
    for k in range(cubic.shape[0]):
        out[k] = ((cubic[k, 0] * t + cubic[k, 1]) * t + cubic[k, 2]) * t + cubic[k, 3]


@njit(cache=True, nogil=True, fastmath=_REORDER)
def _inside(x0: float, y0: float, h: int, w: int, taps: int, rows: int, cols: int) -> bool:
    before = taps // 2 - 1
    after = taps // 2
    ix = math.floor(x0)
    iy = math.floor(y0)
    return ix - before >= 0 and ix + w - 1 + after <= cols - 1 and iy - before >= 0 and iy + h - 1 + after <= rows - 1


@njit(cache=True, nogil=True, fastmath=_REORDER)
def sample_block(image: np.ndarray, x0: float, y0: float, cubic: np.ndarray, tmp: np.ndarray,
                 out: np.ndarray) -> None:
    """``out`` (h, w) = the image interpolated at columns x0 + c, rows y0 + r (support inside the image);
    ``tmp`` (h + taps - 1, w) scratch. Along rows, then along columns, as :func:`vibro_dic.interp.sample_block`;
    each output is one expression of its 4 or 6 taps, so the loops along a row vectorise."""
    taps = cubic.shape[0]
    before = taps // 2 - 1
    h, w = out.shape
    ix = math.floor(x0)
    iy = math.floor(y0)
    wx = np.empty(taps, dtype=np.float32)
    wy = np.empty(taps, dtype=np.float32)
    _weights(x0 - ix, cubic, wx)
    _weights(y0 - iy, cubic, wy)
    x = ix - before
    if taps == 6:
        a0, a1, a2, a3, a4, a5 = wx[0], wx[1], wx[2], wx[3], wx[4], wx[5]
        for r in range(h + 5):
            src = image[iy - before + r, x:x + w + 5]
            dst = tmp[r]
            for c in range(w):
                dst[c] = (a0 * src[c] + a1 * src[c + 1] + a2 * src[c + 2] + a3 * src[c + 3] + a4 * src[c + 4]
                          + a5 * src[c + 5])
        b0, b1, b2, b3, b4, b5 = wy[0], wy[1], wy[2], wy[3], wy[4], wy[5]
        for r in range(h):
            dst = out[r]
            t0, t1, t2, t3, t4, t5 = tmp[r], tmp[r + 1], tmp[r + 2], tmp[r + 3], tmp[r + 4], tmp[r + 5]
            for c in range(w):
                dst[c] = b0 * t0[c] + b1 * t1[c] + b2 * t2[c] + b3 * t3[c] + b4 * t4[c] + b5 * t5[c]
    else:  # 4 taps
        a0, a1, a2, a3 = wx[0], wx[1], wx[2], wx[3]
        for r in range(h + 3):
            src = image[iy - before + r, x:x + w + 3]
            dst = tmp[r]
            for c in range(w):
                dst[c] = a0 * src[c] + a1 * src[c + 1] + a2 * src[c + 2] + a3 * src[c + 3]
        b0, b1, b2, b3 = wy[0], wy[1], wy[2], wy[3]
        for r in range(h):
            dst = out[r]
            t0, t1, t2, t3 = tmp[r], tmp[r + 1], tmp[r + 2], tmp[r + 3]
            for c in range(w):
                dst[c] = b0 * t0[c] + b1 * t1[c] + b2 * t2[c] + b3 * t3[c]


@njit(cache=True, nogil=True, fastmath=_REORDER)
def _window_sums(g: np.ndarray, oy: int, ox: int, h: int, w: int, proj: np.ndarray
                 ) -> tuple[float, float, float, float, float]:
    """Over the (h, w) window of g at (oy, ox): sum g, f~.g, the two H^-1 grad.g rows (``proj`` (4, h*w), rows
    1-3: :class:`vibro_dic.icgn.IcgnBlocks`), and g.g."""
    s_g = 0.0
    f_g = 0.0
    hx = 0.0
    hy = 0.0
    gg = 0.0
    p1, p2, p3 = proj[1], proj[2], proj[3]
    for r in range(h):
        row = g[oy + r, ox:ox + w]
        base = r * w
        q1, q2, q3 = p1[base:base + w], p2[base:base + w], p3[base:base + w]
        for c in range(w):
            v = np.float64(row[c])
            s_g += v
            f_g += q1[c] * v
            hx += q2[c] * v
            hy += q3[c] * v
            gg += v * v
    return s_g, f_g, hx, hy, gg


# Flat argument list on purpose: a numba nopython kernel takes arrays and scalars, not records.
@njit(cache=True, nogil=True, fastmath=_REORDER)
def refine_box(image: np.ndarray, corner_x: float, corner_y: float, ux0: float, uy0: float,  # noqa: PLR0913
               proj: np.ndarray, df: float, du_fx: float, du_fy: float, cubic: np.ndarray, max_move_px: float,
               max_iter: int, tol_px: float, g: np.ndarray, tmp: np.ndarray) -> tuple[int, float, float, float]:
    """IC-GN of one block (top-left ``corner_*`` px in the reference, size ``g.shape``) from (ux0, uy0) px.

    ``proj`` (4, h*w), ``df``, ``du_f*``: the block's constants (:class:`vibro_dic.icgn.IcgnBlocks`).
    Returns (code, ux, uy, zncc): CONVERGED with the u at which ``g`` was last sampled (its step below
    ``tol_px``) and the ZNCC there, else the reason it stopped (the other codes)."""
    rows, cols = image.shape
    h, w = g.shape
    taps = cubic.shape[0]
    n = h * w
    ux = ux0
    uy = uy0
    tol2 = tol_px * tol_px
    for _ in range(max_iter):
        if abs(ux - ux0) > max_move_px or abs(uy - uy0) > max_move_px:
            return MOVED_TOO_FAR, ux, uy, math.nan
        if not _inside(corner_x + ux, corner_y + uy, h, w, taps, rows, cols):
            return LEFT_IMAGE, ux, uy, math.nan
        sample_block(image, corner_x + ux, corner_y + uy, cubic, tmp, g)
        s_g, f_g, hx, hy, gg = _window_sums(g, 0, 0, h, w, proj)
        dg2 = gg - s_g * s_g / n
        if not dg2 > 1e-6:
            return NO_TEXTURE, ux, uy, math.nan
        dg = math.sqrt(dg2)
        scale = df / dg
        dux = du_fx - scale * hx
        duy = du_fy - scale * hy
        if dux * dux + duy * duy <= tol2:
            return CONVERGED, ux, uy, f_g / (df * dg)
        ux += dux
        uy += duy
    return NOT_CONVERGED, ux, uy, math.nan


@njit(cache=True, nogil=True, fastmath=_REORDER)
def subset_steps(g: np.ndarray, offsets: np.ndarray, proj: np.ndarray, df: np.ndarray, du_f: np.ndarray,
                 du: np.ndarray, zncc: np.ndarray, ok: np.ndarray) -> None:
    """One Gauss-Newton step of each subset i, whose samples are the window of ``g`` (the box's samples) at
    ``offsets[i]`` = (x, y) px: ``du`` (m, 2) px to add, ``zncc`` (m,) at the box's u, ``ok`` (m,): textured.
    ``proj`` (m, 4, s*s), ``df`` (m,), ``du_f`` (m, 2): the subsets' constants (:class:`IcgnBlocks`)."""
    m = offsets.shape[0]
    n = proj.shape[2]
    side = int(round(math.sqrt(n)))  # square subsets
    for i in range(m):
        s_g, f_g, hx, hy, gg = _window_sums(g, offsets[i, 1], offsets[i, 0], side, side, proj[i])
        dg2 = gg - s_g * s_g / n
        if dg2 > 1e-6:
            dg = math.sqrt(dg2)
            scale = df[i] / dg
            ok[i] = True
            zncc[i] = f_g / (df[i] * dg)
            du[i, 0] = du_f[i, 0] - scale * hx
            du[i, 1] = du_f[i, 1] - scale * hy
        else:
            ok[i] = False
            zncc[i] = math.nan
            du[i, 0] = 0.0
            du[i, 1] = 0.0


@njit(cache=True, nogil=True)
def _median(values: np.ndarray) -> float:
    s = np.sort(values)
    k = len(s)
    return 0.5 * (s[(k - 1) // 2] + s[k // 2])


# Flat arguments and one hot loop body on purpose: a numba nopython kernel takes arrays and scalars, not records.
@njit(cache=True, nogil=True)
def combine_points(u: np.ndarray, zncc: np.ndarray, converged: np.ndarray,  # noqa: PLR0913, C901
                   zncc_min: float, outlier_k: float, outlier_floor_px: float, arms: np.ndarray,
                   min_arm_spread_px2: float, valid: np.ndarray
                   ) -> tuple[int, float, float, float, float, float, float, float, float]:
    """A mesh's displacement from its points ``u`` (N, 2) px: ``valid`` (N,) is set to the points kept
    (converged, ZNCC >= ``zncc_min``, finite, within max(``outlier_k`` robust sigmas, ``outlier_floor_px``)
    of the median on both axes). Returns (kept, mean ux, mean uy, mean ZNCC of the kept, theta rad, its
    sigma rad, residual sigma px per point and axis, the kept points' mean arm x, y) with theta from
    u_i = t + theta a_i (``arms`` (N, 2) px per rad; NaN when fewer than 2 points or the arms spread less
    than ``min_arm_spread_px2``)."""
    nan = math.nan
    n = u.shape[0]
    m = 0
    for i in range(n):
        # NaN compares False, so a point without a ZNCC is no candidate
        valid[i] = converged[i] and zncc[i] >= zncc_min and math.isfinite(u[i, 0]) and math.isfinite(u[i, 1])
        m += valid[i]
    if m:
        ux = np.empty(m)
        uy = np.empty(m)
        j = 0
        for i in range(n):
            if valid[i]:
                ux[j] = u[i, 0]
                uy[j] = u[i, 1]
                j += 1
        mx = _median(ux)
        my = _median(uy)
        tx = max(outlier_k * 1.4826 * _median(np.abs(ux - mx)), outlier_floor_px)
        ty = max(outlier_k * 1.4826 * _median(np.abs(uy - my)), outlier_floor_px)
        for i in range(n):
            if valid[i] and not (abs(u[i, 0] - mx) <= tx and abs(u[i, 1] - my) <= ty):
                valid[i] = False
    kept = 0
    sx = sy = sz = ax = ay = 0.0
    for i in range(n):
        if valid[i]:
            kept += 1
            sx += u[i, 0]
            sy += u[i, 1]
            sz += zncc[i]
            ax += arms[i, 0]
            ay += arms[i, 1]
    if kept == 0:
        return 0, nan, nan, nan, nan, nan, nan, nan, nan
    mean_x, mean_y, mean_ax, mean_ay = sx / kept, sy / kept, ax / kept, ay / kept
    theta = sigma_theta = sigma = nan
    if kept >= 2:
        spread = 0.0
        cross = 0.0
        for i in range(n):
            if valid[i]:
                dax, day = arms[i, 0] - mean_ax, arms[i, 1] - mean_ay
                spread += dax * dax + day * day
                cross += (u[i, 0] - mean_x) * dax + (u[i, 1] - mean_y) * day
        if spread >= min_arm_spread_px2:
            theta = cross / spread
            dof = 2 * kept - 3
            if dof >= 1:
                ss = 0.0
                for i in range(n):
                    if valid[i]:
                        rx = u[i, 0] - mean_x - theta * (arms[i, 0] - mean_ax)
                        ry = u[i, 1] - mean_y - theta * (arms[i, 1] - mean_ay)
                        ss += rx * rx + ry * ry
                sigma = math.sqrt(ss / dof)
                sigma_theta = sigma / math.sqrt(spread)
    return kept, mean_x, mean_y, sz / kept, theta, sigma_theta, sigma, mean_ax, mean_ay
