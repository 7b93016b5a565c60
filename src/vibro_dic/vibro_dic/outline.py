"""A plain ball (no speckle) tracked by its outline: edge points to sub-pixel, a robust circle fit, its accuracy.

Real bounce footage rarely has a speckled ball: a backlit ball is a dark disc with a sharp outline on a bright
background (``vibro synth --ball-surface plain``, the Photron file ``ball_12bit``). DIC subsets inside such a
disc hold no texture; its outline holds all the information. rig.yaml ``dic.ball_method: outline`` tracks it
here; ``dic.ball_roi`` is then a box around the whole ball in frame 0 with a margin (what a user draws).

Per frame (pixels, x = column, y = row down):

1. **Prediction** of the centre from the last good frames (constant acceleration from three, velocity from
   two; frame indices, so dropped frames are handled), as the DIC mesh does. Without history (frame 1, a
   re-seed every ``reseed_every`` frames, a lost frame) or when step 2 fails, the reference box is found by
   an integer ZNCC search (:func:`vibro_dic.search.zncc_search`), widened to the whole image if need be
   (coarse to fine: :func:`vibro_dic.search.whole_image_search`).
2. **Coarse edge points along rays** from the predicted centre, one ray per sector direction: the profile
   sampled every 0.5 px (bilinear) over +-``reach`` px about the reference radius, the edge at the strongest
   gradient of the reference's sign (dark inside: rising outwards), to a parabola through the peak. The
   centre offset then follows from the edge radii e_i = R + d . u_i (R the reference radius, u_i the ray's
   unit vector) by iteratively reweighted least squares (Tukey, scale from the MAD): rays that meet a plate,
   a holder or a shadow instead of the outline are outliers. A coarse centre good to ~0.1 px.
3. **Sub-pixel edges per sector** about that centre: the pixels of the edge band (|r - R| <= band) are split
   into ``n_sectors`` angular sectors (~4 px of arc each); in each sector the gray levels are fitted by an
   erf edge I(r) = o + c Phi + (r - R) (s_out (1 - Phi) + s_in Phi), Phi = Phi((e - r) / w) (o the outside
   level, c = inside - outside the contrast, e the edge radius, w the edge's blur sigma: lens, pixel area,
   motion blur; s_out, s_in gray-level slopes outside and inside: a backlight's gradient, a ball's shading,
   which would otherwise pull the edge) by Gauss-Newton, from the pixels themselves (no interpolation: the
   pixel noise stays white). Each sector's edge sigma is the Cramer-Rao bound of that fit,
   s_e^2 = noise^2 [(J^T J)^-1]_ee; without the image noise, the fit's residual std. The sectors are cut
   about the centre they find (fits repeated about the fitted centre until it moves < 0.002 px).
4. **Robust circle fit** of the sectors' edge points P_k = c + e_k u_k (u_k the sector's gradient-weighted
   direction) by geometric Gauss-Newton on (centre, radius), weights 1 / s_e^2, iteratively reweighted
   (Tukey): a sector whose contrast or blur differs from the reference's (:data:`CONTRAST_TOLERANCE`,
   :data:`MAX_BLUR_GROWTH`) is occluded and left out before, a sector off the circle by more than the
   Tukey limit after. The centre, the radius and their 1-sigma: ``sigma_px`` from the residuals
   (chi^2 per degree of freedom, at least 1, times the propagated covariance) and ``sigma_pred_px`` from the
   sectors' Cramer-Rao bounds alone.
5. **Displacement** = centre - the reference's centre (both fitted the same way, so a constant bias of the
   edge model, e.g. a clipped backlight or a refracting glass ball, cancels); its sigma sqrt(2) x the
   centre's (both frames are noisy). In-plane rotation: not measured (NaN): a plain disc looks the same at
   any angle.

**Lost**: the disc and its edge band leave the image, no outline found, or fewer than ``min_valid_fraction``
of the sectors kept.

**Accuracy before tracking** (:func:`assess_outline`, the analogue of the SSSIG check of speckle): the
reference frame's fit with the image noise gives each sector's s_e from the edge contrast c, the blur w and
the pixels in the band (a sector whose fit leaves a residual std above the noise, a real ball's refraction or
a clipped backlight, counts that misfit as its noise), and the circle fit propagates them over the N sectors:
the predicted displacement sigma per axis, about sqrt(2) x sqrt(2 / N) x s_e with
s_e ~ noise sqrt(2 sqrt(pi) w / rho) / |c| (rho the sector's pixels per px of radius; the exact propagation is
used). Refused (:class:`~vibro_dic.texture.
TextureError`), with the numbers, when no disc is found in the ROI, the outline leaves the image, the
contrast is below :data:`MIN_CONTRAST_TO_NOISE` x the noise, fewer sectors than the tracker needs are
usable, or the predicted sigma exceeds ``max_sigma_px``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

from vibro_io.rig import Roi
from vibro_model.errors import RecordingError

from .search import half_resolution, whole_image_search, zncc_search

SECTOR_ARC_PX = 4.0          # arc length of a sector at the ball's radius (px): ~4 px of edge per sector
MIN_SECTORS, MAX_SECTORS = 16, 256
MIN_SECTOR_PIXELS = 8        # a sector with fewer band pixels (image border) is not fitted
BAND_SIGMAS = 4.0            # the edge band reaches this many edge sigmas ...
BAND_EXTRA_PX = 2.0          # ... plus this, on either side of the radius (px)
MIN_BAND_PX, MAX_BAND_PX = 3.0, 12.0
GN_ITERATIONS = 10           # Gauss-Newton steps of the sector fits, at most ...
SECTOR_PARAMS = 6            # o, c, e, w, s_out, s_in of a sector's edge model
GN_TOL_PX = 1e-4             # ... until no sector's edge or blur moves more than this (px)
#: a sector whose contrast differs from the reference sector's by more than this share is occluded
CONTRAST_TOLERANCE = 0.35
#: ... or whose edge sigma exceeds this many times the reference's plus the motion blur allowance
MAX_BLUR_GROWTH = 4.0
BLUR_ALLOWANCE_PX = 1.5
MAX_RESIDUAL_RATIO = 2.5     # a sector fitted this many times worse than the median sector is not the outline
TUKEY_C = 4.685              # Tukey biweight limit (in robust standard deviations)
MIN_CONTRAST_TO_NOISE = 10.0  # an outline weaker than this (|contrast| / noise) is refused
DEFAULT_MAX_OUTLINE_SIGMA_PX = 0.05
RAY_STEP_PX = 0.5            # sample spacing of the coarse rays
DEFAULT_REACH_PX = 6.0       # the coarse rays reach +- this (px) beyond the predicted motion ...
WIDE_REACH_FACTOR = 3.0      # ... and this many times it when the first try fails
MIN_COARSE_FRACTION = 0.4    # coarse edges needed (share of the rays)
FIXED_POINT_PASSES = 4       # sector fits about the last fitted centre, at most this many ...
FIXED_POINT_TOL_PX = 0.002   # ... until the centre moves less than this (px)


class OutlineError(RecordingError):
    """No usable ball outline (no disc in the ROI, too weak, or leaving the image)."""


# ------------------------------------------------------------------------------------------- frame 0: find it
@dataclass(frozen=True)
class Disc:
    """A disc found by its silhouette: centre (x, y) px, radius px, its polarity (+1 darker than the
    background, -1 brighter) and how round its outline is (std of the contour's radius / radius)."""

    cx: float
    cy: float
    radius_px: float
    polarity: int
    roundness: float
    inside_gray: float
    outside_gray: float


def find_disc(image: np.ndarray, roi: Roi, *, max_roundness: float = 0.06) -> Disc | None:
    """The disc in ``roi`` of ``image`` (2-D): Otsu's threshold splits the ROI in two; the class that holds
    most of the ROI's border is the background, the largest connected region of the other class, its holes
    filled (a highlight inside a dark ball), is the disc. None when there is none, when it touches the ROI's
    border (not a whole ball inside a box with a margin), or when its outline is not round (contour radius
    std / radius > ``max_roundness``)."""
    img = np.asarray(image, dtype=np.float64)
    box = img[roi.y:roi.y + roi.h, roi.x:roi.x + roi.w]
    if box.size < 64 or min(box.shape) < 8:
        return None
    lo, hi = float(box.min()), float(box.max())
    if not hi > lo:
        return None
    u8 = np.rint((box - lo) * (255.0 / (hi - lo))).astype(np.uint8)
    _, bright = cv2.threshold(u8, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    border = np.concatenate([bright[0], bright[-1], bright[:, 0], bright[:, -1]])
    polarity = 1 if border.mean() >= 0.5 else -1  # background bright: the disc is darker
    fg = (bright == 0) if polarity == 1 else (bright == 1)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8), connectivity=8)
    if n < 2:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h = (int(v) for v in stats[k, :4])
    if x == 0 or y == 0 or x + w >= box.shape[1] or y + h >= box.shape[0]:
        return None
    contours, _ = cv2.findContours((labels == k).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=len)[:, 0, :].astype(np.float64)
    filled = np.zeros(box.shape, np.uint8)
    cv2.drawContours(filled, [contour.astype(np.int32)[:, None, :]], -1, 1, thickness=cv2.FILLED)
    area = float(filled.sum())
    if area < 20:
        return None
    ys, xs = np.nonzero(filled)
    cx, cy = float(xs.mean()), float(ys.mean())
    radius = math.sqrt(area / math.pi)
    d = np.hypot(contour[:, 0] - cx, contour[:, 1] - cy)
    roundness = float(d.std() / max(d.mean(), 1e-9))
    if roundness > max_roundness:
        return None
    inside = float(np.median(box[filled.astype(bool)]))
    outside = float(np.median(box[~cv2.dilate(filled, np.ones((5, 5), np.uint8)).astype(bool)]))
    return Disc(cx + roi.x, cy + roi.y, radius, polarity, roundness, inside, outside)


# ----------------------------------------------------------------------------------------- step 2: coarse
def coarse_edges(image: np.ndarray, centre: np.ndarray, radius: float, directions: np.ndarray, reach_px: float,
                 polarity: int, min_gradient: float) -> np.ndarray:
    """(n,) edge radius (px from ``centre``) along each unit ``direction`` (n, 2): the strongest gradient of the
    outline's sign (``polarity`` +1: rising outwards) within radius +- ``reach_px``, to a parabola through its
    peak; NaN where no gradient reaches ``min_gradient`` (gray levels per px) or the ray leaves the image."""
    s = np.arange(max(radius - reach_px, 0.3 * radius), radius + reach_px + 1e-9, RAY_STEP_PX)
    xs = (centre[0] + directions[:, 0, None] * s[None, :]).astype(np.float32)
    ys = (centre[1] + directions[:, 1, None] * s[None, :]).astype(np.float32)
    prof = cv2.remap(np.asarray(image, np.float32), xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=float("nan"))
    grad = polarity * np.diff(prof, axis=1) / RAY_STEP_PX  # (n, m - 1) at the mid-samples
    grad = np.where(np.isfinite(grad), grad, -np.inf)
    i = np.argmax(grad, axis=1)
    n, m = grad.shape
    rows = np.arange(n)
    peak = grad[rows, i]
    left = grad[rows, np.maximum(i - 1, 0)]
    right = grad[rows, np.minimum(i + 1, m - 1)]
    den = left - 2.0 * peak + right
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where((i > 0) & (i < m - 1) & (den < 0) & np.isfinite(den), 0.5 * (left - right) / den, 0.0)
    e = s[0] + (i + 0.5 + np.clip(off, -0.5, 0.5)) * RAY_STEP_PX
    ok = (peak >= min_gradient) & np.isfinite(prof).all(axis=1)
    return np.where(ok, e, np.nan)


def _tukey(z: np.ndarray) -> np.ndarray:
    """Tukey biweight of standardized residuals ``z`` (0 beyond :data:`TUKEY_C`)."""
    t = np.clip(np.abs(z) / TUKEY_C, 0.0, 1.0)
    return (1.0 - t * t) ** 2


def robust_offset(edges: np.ndarray, radius: float, directions: np.ndarray, *, iterations: int = 6,
                  floor_px: float = 0.2) -> tuple[np.ndarray, np.ndarray] | None:
    """Centre offset d (2,) px from the edge radii ``edges`` (n,) along unit ``directions`` (n, 2) of a circle of
    known ``radius``: e_i = radius + d . u_i, iteratively reweighted (Tukey; scale 1.4826 MAD, at least
    ``floor_px``). Returns (d, kept mask) or None with fewer than 3 finite edges."""
    ok = np.isfinite(edges)
    if np.count_nonzero(ok) < 3:
        return None
    A, b = directions[ok], edges[ok] - radius
    d = np.linalg.lstsq(A, b, rcond=None)[0]  # a plain least-squares start
    w = np.ones(len(b))
    for _ in range(iterations):
        r = b - A @ d
        scale = max(1.4826 * float(np.median(np.abs(r - np.median(r)))), floor_px)
        w = _tukey(r / scale)
        if np.count_nonzero(w) < 3:
            return None
        Aw = A * w[:, None]
        try:
            d = np.linalg.solve(Aw.T @ A, Aw.T @ b)
        except np.linalg.LinAlgError:
            return None
    kept = np.zeros(len(edges), bool)
    kept[np.flatnonzero(ok)] = w > 0
    return d, kept


# -------------------------------------------------------------------------------------- step 3: sectors
@dataclass(kw_only=True)
class SectorEdges:
    """Per-sector erf fits of the edge band about a centre (px; angles of the image, y down)."""

    centre: np.ndarray          # (2,) the centre the radii are measured from
    direction: np.ndarray       # (N, 2) gradient-weighted unit direction of each sector
    edge_px: np.ndarray         # (N,) edge radius e_k
    outside: np.ndarray         # (N,) outside level o_k (gray levels)
    contrast: np.ndarray        # (N,) inside - outside c_k (gray levels)
    blur_px: np.ndarray         # (N,) edge sigma w_k
    crb_unit: np.ndarray        # (N,) sqrt([(J^T J)^-1]_ee): the edge sigma per gray level of noise
    residual_std: np.ndarray    # (N,) the fit's residual std (gray levels)
    zncc: np.ndarray            # (N,) ZNCC of the pixels with the fitted edge (1 = the model explains them)
    variance: np.ndarray        # (N,) gray-level variance of the sector's pixels
    n_pixels: np.ndarray        # (N,)
    ok: np.ndarray              # (N,) fitted (enough pixels, converged, finite)


def sector_edges(image: np.ndarray, centre: np.ndarray, radius: float, n_sectors: int, band_px: float,
                 start: SectorEdges | None = None, blur0_px: float = 1.0) -> SectorEdges:
    """Fit the erf edge I(r) = o + c Phi + (r - ``radius``) (s_out (1 - Phi) + s_in Phi), Phi = Phi((e - r) / w),
    in each of ``n_sectors`` angular sectors of the band |r - ``radius``| <= ``band_px`` about ``centre`` (module
    doc, step 3; s_out and s_in, gray-level slopes outside and inside the edge, take up a backlight's gradient
    and a ball's shading). ``start``: the reference's fits
    (their o, c, w start the iteration; else from the band's inner and outer pixels, w = ``blur0_px``)."""
    from scipy.special import ndtr  # here, not at import: ~0.2 s CPU at every tracker's start, for this method only

    img = np.asarray(image)
    H, W = img.shape
    cx, cy = float(centre[0]), float(centre[1])
    reach = radius + band_px + 1.0
    x0, x1 = max(int(math.floor(cx - reach)), 0), min(int(math.ceil(cx + reach)) + 1, W)
    y0, y1 = max(int(math.floor(cy - reach)), 0), min(int(math.ceil(cy + reach)) + 1, H)
    dx, dy = np.meshgrid(np.arange(x0, x1) - cx, np.arange(y0, y1) - cy)
    r = np.hypot(dx, dy)
    band = np.abs(r - radius) <= band_px
    g = img[y0:y1, x0:x1][band].astype(np.float64)
    r, dx, dy = r[band], dx[band], dy[band]
    sec = np.minimum(((np.arctan2(dy, dx) + math.pi) * (n_sectors / (2 * math.pi))).astype(np.intp), n_sectors - 1)
    N = n_sectors
    rr = r - radius

    def sums(v):
        return np.bincount(sec, weights=v, minlength=N)

    def model_and_jacobian(p):
        o, c, e, w, s_out, s_in = (q[sec] for q in p.T)
        z = (e - r) / w
        phi = np.exp(-0.5 * z * z) * (1.0 / math.sqrt(2 * math.pi))
        Phi = ndtr(z)
        step = c + rr * (s_in - s_out)  # the jump across the edge at this pixel's radius
        return (o + c * Phi + rr * (s_out + (s_in - s_out) * Phi),
                (np.ones_like(r), Phi, step * phi / w, -step * phi * z / w, rr * (1.0 - Phi), rr * Phi))

    def normal(J, res):
        JtJ = np.empty((N, SECTOR_PARAMS, SECTOR_PARAMS))
        for a in range(SECTOR_PARAMS):
            for b in range(a, SECTOR_PARAMS):
                JtJ[:, a, b] = JtJ[:, b, a] = sums(J[a] * J[b])
        return JtJ, np.stack([sums(j * res) for j in J], axis=1)

    npx = np.bincount(sec, minlength=N).astype(float)
    good = npx >= MIN_SECTOR_PIXELS
    p = np.zeros((N, SECTOR_PARAMS))
    p[:, 2] = radius
    if start is not None:
        p[:, 0], p[:, 1], p[:, 3] = start.outside, start.contrast, np.maximum(start.blur_px, 0.3)
    else:
        outer, inner = (rr > 0.5 * band_px).astype(float), (rr < -0.5 * band_px).astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            p[:, 0] = sums(g * outer) / sums(outer)
            p[:, 1] = sums(g * inner) / sums(inner) - p[:, 0]
        p[:, 3] = blur0_px
    p = np.where(np.isfinite(p), p, 0.0)
    for _ in range(GN_ITERATIONS):
        model, J = model_and_jacobian(p)
        JtJ, Jtr = normal(J, g - model)
        JtJ += np.eye(SECTOR_PARAMS)[None] * 1e-9 * np.trace(JtJ, axis1=1, axis2=2)[:, None, None]
        step = np.zeros((N, SECTOR_PARAMS))
        with np.errstate(all="ignore"):
            try:
                step[good] = np.linalg.solve(JtJ[good], Jtr[good][..., None])[..., 0]
            except np.linalg.LinAlgError:
                step[good] = np.nan
        step = np.where(np.isfinite(step), step, 0.0)
        step[:, 2] = np.clip(step[:, 2], -2.0, 2.0)
        step[:, 3] = np.clip(step[:, 3], -0.5 * p[:, 3], p[:, 3])
        p += step
        p[:, 2] = np.clip(p[:, 2], radius - band_px, radius + band_px)
        p[:, 3] = np.clip(p[:, 3], 0.2, band_px)
        if float(np.max(np.abs(step[:, 2:4]))) < GN_TOL_PX:
            break
    model, J = model_and_jacobian(p)
    res = g - model
    JtJ, _ = normal(J, res)
    ok_fit = good & np.isfinite(JtJ).all(axis=(1, 2))
    crb = np.full(N, np.nan)
    with np.errstate(all="ignore"):
        safe = np.where(ok_fit[:, None, None], JtJ, np.eye(SECTOR_PARAMS))
        ok_fit &= np.abs(np.linalg.det(safe)) > 0
        inv = np.linalg.inv(np.where(ok_fit[:, None, None], JtJ, np.eye(SECTOR_PARAMS)))
    crb[ok_fit] = np.sqrt(np.maximum(inv[ok_fit, 2, 2], 0.0))
    n1 = np.maximum(npx, 1)
    rstd = np.sqrt(sums(res * res) / np.maximum(npx - SECTOR_PARAMS, 1))
    mg, mm = sums(g) / n1, sums(model) / n1
    vg, vm = sums(g * g) / n1 - mg ** 2, sums(model * model) / n1 - mm ** 2
    with np.errstate(all="ignore"):
        zncc = (sums(g * model) / n1 - mg * mm) / np.sqrt(vg * vm)
    wgt = J[2] ** 2  # the sector's direction: the gradient-weighted mean of its pixels' directions
    ux, uy = sums(wgt * dx / np.maximum(r, 1e-9)), sums(wgt * dy / np.maximum(r, 1e-9))
    with np.errstate(all="ignore"):
        direction = np.column_stack([ux, uy]) / np.hypot(ux, uy)[:, None]
    o, c, e, w = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
    ok = ok_fit & np.isfinite(crb) & (crb > 0) & np.isfinite(direction).all(axis=1) \
        & (np.abs(e - radius) < band_px - 1e-6) & (w < band_px)
    return SectorEdges(centre=np.array([cx, cy]), direction=direction, edge_px=e, outside=o, contrast=c, blur_px=w,
                       crb_unit=crb, residual_std=rstd, zncc=zncc, variance=np.maximum(vg, 0.0), n_pixels=npx, ok=ok)


# --------------------------------------------------------------------------------- step 4: circle fit
@dataclass
class CircleFit:
    """A robust circle through sector edge points: centre (x, y) px, radius px, their 1-sigma."""

    centre: np.ndarray           # (2,)
    radius_px: float
    sigma_px: np.ndarray         # (3,) 1-sigma of (x, y, radius) from the residuals (chi^2/dof >= 1)
    sigma_pred_px: np.ndarray    # (3,) 1-sigma of (x, y, radius) from the edge sigmas alone
    kept: np.ndarray             # (N,) sectors used
    residual_px: np.ndarray      # (N,) distance of each edge point from the circle (NaN when not fitted)
    chi2_dof: float


def fit_circle(points: np.ndarray, sigma: np.ndarray, usable: np.ndarray, centre0: np.ndarray, radius0: float,
               *, iterations: int = 8) -> CircleFit | None:
    """Geometric circle fit of ``points`` (N, 2) px with edge sigmas ``sigma`` (N,) px, ``usable`` (N,) bool,
    from (``centre0``, ``radius0``): Gauss-Newton on the distances, weights 1 / sigma^2 x Tukey of the
    standardized residuals (scale 1.4826 MAD of them, at least 1). None with fewer than 4 usable points."""
    idx = np.flatnonzero(usable & np.isfinite(points).all(axis=1) & np.isfinite(sigma) & (sigma > 0))
    if idx.size < 4:
        return None
    P, s = points[idx], sigma[idx]
    c, R = np.asarray(centre0, float).copy(), float(radius0)
    rob = np.ones(idx.size)
    for it in range(iterations):
        d = P - c
        dist = np.hypot(d[:, 0], d[:, 1])
        u = d / dist[:, None]
        res = dist - R
        z = res / s
        if it >= 1:  # the first step from the coarse centre unweighted by residuals
            scale = max(1.4826 * float(np.median(np.abs(z - np.median(z)))), 1.0)
            rob = _tukey(z / scale)
            if np.count_nonzero(rob) < 4:
                return None
        A = np.column_stack([-u, -np.ones(idx.size)])  # d(res)/d(cx, cy, R)
        wts = rob / (s * s)
        Aw = A * wts[:, None]
        try:
            step = np.linalg.solve(Aw.T @ A, -(Aw.T @ res))
        except np.linalg.LinAlgError:
            return None
        c += step[:2]
        R += step[2]
        if float(np.abs(step).max()) < 1e-7:
            break
    d = P - c
    dist = np.hypot(d[:, 0], d[:, 1])
    u = d / dist[:, None]
    res = dist - R
    kept_local = rob > 0
    A = np.column_stack([-u, -np.ones(idx.size)])[kept_local]
    wts = 1.0 / (s[kept_local] ** 2)
    try:
        cov_pred = np.linalg.inv((A * wts[:, None]).T @ A)
    except np.linalg.LinAlgError:
        return None
    dof = max(int(kept_local.sum()) - 3, 1)
    chi2 = float(np.sum(wts * res[kept_local] ** 2) / dof)
    sig_pred = np.sqrt(np.diag(cov_pred))
    kept = np.zeros(len(points), bool)
    kept[idx[kept_local]] = True
    residual = np.full(len(points), np.nan)
    residual[idx] = res
    return CircleFit(c, R, sig_pred * math.sqrt(max(chi2, 1.0)), sig_pred, kept, residual, chi2)


# -------------------------------------------------------------------------------------- one outline fit
@dataclass
class OutlineFit:
    """The outline of the ball in one image: the sectors' edges and the circle through them."""

    sectors: SectorEdges
    circle: CircleFit
    usable: np.ndarray  # (N,) sectors not occluded (contrast, blur, fit) before the circle fit


def reference_levels(reference: SectorEdges) -> tuple[np.ndarray, np.ndarray]:
    """(contrast, blur) per sector that a later frame's sectors are compared with: the reference's own where its
    fit was clean, the median over its clean sectors where it was not (a plate in the band of frame 0)."""
    clean = reference.ok & (reference.residual_std <= MAX_RESIDUAL_RATIO * float(
        np.median(reference.residual_std[reference.ok])) if reference.ok.any() else reference.ok)
    if not clean.any():
        return reference.contrast, reference.blur_px
    return (np.where(clean, reference.contrast, np.median(reference.contrast[clean])),
            np.where(clean, reference.blur_px, np.median(reference.blur_px[clean])))


def sector_count(radius_px: float) -> int:
    """Sectors of ~:data:`SECTOR_ARC_PX` of arc each on a ball of ``radius_px``."""
    return int(np.clip(round(2 * math.pi * radius_px / SECTOR_ARC_PX), MIN_SECTORS, MAX_SECTORS))


def edge_points(fit: OutlineFit) -> np.ndarray:
    """(K, 2) px: the edge points P_k = c + e_k u_k of the sectors the circle fit kept."""
    sec = fit.sectors
    return (sec.centre[None, :] + sec.edge_px[:, None] * sec.direction)[fit.circle.kept]


def band_width(blur_px: float) -> float:
    """Half-width (px) of the edge band about the radius for an edge of sigma ``blur_px``."""
    return float(np.clip(BAND_SIGMAS * blur_px + BAND_EXTRA_PX, MIN_BAND_PX, MAX_BAND_PX))


def fit_outline(image: np.ndarray, centre: np.ndarray, radius: float, n_sectors: int, band_px: float, *,
                reference: SectorEdges | None = None, noise_gray: float | None = None,
                blur0_px: float = 1.0) -> OutlineFit | None:
    """Sector edges about ``centre`` (step 3) and the robust circle through them (step 4). ``reference``: the
    reference frame's sectors (occlusion tests against their contrast and blur; start values); ``noise_gray``:
    the image noise (the edge sigmas are then the Cramer-Rao bounds; None: each sector's residual std)."""
    sec = sector_edges(image, centre, radius, n_sectors, band_px, start=reference, blur0_px=blur0_px)
    usable = sec.ok.copy()
    if not usable.any():
        return None
    # a sector whose pixels the edge model explains much worse than the others' holds something else (a plate's
    # speckle in its band, a holder, a shadow's edge)
    usable &= sec.residual_std <= MAX_RESIDUAL_RATIO * float(np.median(sec.residual_std[usable]))
    with np.errstate(invalid="ignore"):
        if reference is not None:
            c_ref, w_ref = reference_levels(reference)
            usable &= np.abs(sec.contrast - c_ref) <= CONTRAST_TOLERANCE * np.abs(c_ref)
            usable &= sec.blur_px <= MAX_BLUR_GROWTH * w_ref + BLUR_ALLOWANCE_PX
        else:
            med = float(np.median(sec.contrast[usable]))
            usable &= np.abs(sec.contrast - med) <= CONTRAST_TOLERANCE * abs(med)
    noise = sec.residual_std if noise_gray is None else np.full(n_sectors, float(noise_gray))
    sigma_e = sec.crb_unit * noise
    points = sec.centre[None, :] + sec.edge_px[:, None] * sec.direction
    circle = fit_circle(points, sigma_e, usable, sec.centre, radius)
    if circle is None:
        return None
    return OutlineFit(sec, circle, usable)


# ------------------------------------------------------------------------------------------ the tracker
@dataclass(kw_only=True)
class OutlineResult:
    """What the outline tracker gives for one frame, in the DIC mesh's terms (:class:`~vibro_dic.tracker.
    MeshResult`): ``u_px`` the centre's displacement since the reference, ``valid`` the sectors kept,
    ``zncc`` the mean over kept sectors of the ZNCC between the pixels and the fitted edge model."""

    name: str
    u_px: np.ndarray
    valid: int
    zncc: float
    lost: bool
    reason: str = ""
    point_u_px: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    point_valid: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    point_zncc: np.ndarray = field(default_factory=lambda: np.empty(0))
    rot_rad: float = math.nan
    rot_std_rad: float = math.nan
    sigma_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))  # (2,) of u, from the residuals
    radius_px: float = math.nan
    radius_sigma_px: float = math.nan
    fit: OutlineFit | None = None  # the outline fitted (its edge points: a lens calibration undistorts them)


class OutlineTracker:
    """Tracks a plain ball by its outline against the reference image (module doc). The same interface as a
    DIC mesh (:class:`~vibro_dic.tracker.MeshTracker`): :meth:`track`, :meth:`reseed`, ``points``."""

    def __init__(self, name: str, reference: np.ndarray, roi: Roi, *, min_valid_fraction: float = 0.5):
        self.name = name
        ref = np.asarray(reference, dtype=np.float32)
        self.shape = ref.shape
        disc = find_disc(ref, roi)
        if disc is None:
            raise OutlineError(f"dic.{name}_roi {roi.as_list()}: no disc with a round outline inside it in frame 0 "
                               "(dic.ball_method: outline needs a box around the whole ball, with a margin, on a "
                               "background of one gray level)")
        self.polarity = disc.polarity
        self.roi = roi
        r0 = disc.radius_px
        self.n_sectors = sector_count(r0)
        angles = -math.pi + (np.arange(self.n_sectors) + 0.5) * (2 * math.pi / self.n_sectors)
        self.directions = np.column_stack([np.cos(angles), np.sin(angles)])
        contrast = abs(disc.outside_gray - disc.inside_gray)
        self.min_gradient = 0.1 * contrast
        # the reference: coarse rays about the silhouette's centroid, then the sector fits, twice (the second
        # about the first's centre, with its blur)
        c = np.array([disc.cx, disc.cy])
        fit = None
        blur = 1.0
        for _ in range(3):
            e = coarse_edges(ref, c, r0, self.directions, DEFAULT_REACH_PX, self.polarity, self.min_gradient)
            off = robust_offset(e, r0, self.directions)
            if off is not None:
                c = c + off[0]
                r0 = float(np.nanmedian(e - self.directions @ off[0]))
            fit = fit_outline(ref, c, r0, self.n_sectors, band_width(blur), blur0_px=blur)
            if fit is None:
                break
            c, r0 = fit.circle.centre.copy(), fit.circle.radius_px
            blur = float(np.median(fit.sectors.blur_px[fit.circle.kept]))
        if fit is None or not self._inside(c, r0, band_width(blur)):
            raise OutlineError(f"dic.{name}_roi {roi.as_list()}: the ball's outline (centre {c.round(1).tolist()}, "
                               f"radius {r0:.1f} px) cannot be fitted in frame 0 or leaves the image")
        self.reference_fit = fit
        self.centre0 = fit.circle.centre.copy()
        self.radius0 = fit.circle.radius_px
        self.blur0 = blur
        self.band_px = band_width(blur)
        self.min_valid = max(4, math.ceil(min_valid_fraction * self.n_sectors - 1e-9))
        self.points = self.centre0[None, :] + self.radius0 * self.directions  # (N, 2): one per sector
        half = int(math.ceil(self.radius0 + self.band_px + 2))
        x0 = max(int(round(self.centre0[0])) - half, 0)
        y0 = max(int(round(self.centre0[1])) - half, 0)
        x1 = min(int(round(self.centre0[0])) + half + 1, ref.shape[1])
        y1 = min(int(round(self.centre0[1])) + half + 1, ref.shape[0])
        self.template = np.ascontiguousarray(ref[y0:y1, x0:x1])
        self.template_corner = np.array([x0, y0], dtype=float)
        self._half_template = half_resolution(self.template)  # the whole-image search's coarse level
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=3)
        self.n_searched = 0  # frames that needed the template search (statistics)

    def _inside(self, centre: np.ndarray, radius: float, band_px: float) -> bool:
        reach = radius + band_px + 1.0
        H, W = self.shape
        return bool(centre[0] - reach >= 0 and centre[1] - reach >= 0 and centre[0] + reach <= W - 1
                    and centre[1] + reach <= H - 1)

    def reseed(self) -> None:
        """Forget the motion history: the next frame is searched as if it were the first after frame 0."""
        self.history.clear()

    def predict(self, k: int) -> np.ndarray:
        """Predicted displacement (x, y) px at frame ``k``: Lagrange extrapolation through the history."""
        if not self.history:
            return np.zeros(2)
        ks = [kh for kh, _ in self.history]
        us = np.array([u for _, u in self.history])
        weights = np.ones(len(ks))
        for i, ki in enumerate(ks):
            for j, kj in enumerate(ks):
                if j != i:
                    weights[i] *= (k - kj) / (ki - kj)
        return weights @ us

    def _speed(self) -> float:
        """Fastest recent speed (px/frame) of the history."""
        h = list(self.history)
        return max((float(np.hypot(*(u1 - u0))) / (k1 - k0) for (k0, u0), (k1, u1) in zip(h[:-1], h[1:])),
                   default=0.0)

    def _coarse(self, image: np.ndarray, centre: np.ndarray, reach: float) -> np.ndarray | None:
        e = coarse_edges(image, centre, self.radius0, self.directions, reach, self.polarity, self.min_gradient)
        if np.count_nonzero(np.isfinite(e)) < MIN_COARSE_FRACTION * self.n_sectors:
            return None
        off = robust_offset(e, self.radius0, self.directions)
        if off is None or np.count_nonzero(off[1]) < MIN_COARSE_FRACTION * self.n_sectors:
            return None
        return centre + off[0]

    def _search(self, image: np.ndarray, k: int) -> np.ndarray | None:
        """The reference box found by ZNCC search: around the prediction, widened, then the whole image."""
        self.n_searched += 1
        th, tw = self.template.shape
        pred = self.template_corner + self.predict(k)
        if self.history:
            ext = int(math.ceil(2.0 * self._speed() * max(k - self.history[-1][0], 1) + 8))
            cx, cy = int(round(pred[0])), int(round(pred[1]))
            res = zncc_search(image, self.template, cx - ext, cx + ext, cy - ext, cy + ext)
            if res is not None and not res.on_border and res.zncc >= 0.5:
                return np.array([res.x + res.sub_dx, res.y + res.sub_dy]) - self.template_corner + self.centre0
        res = whole_image_search(image, self.template, self._half_template, 0.5)
        if res is None or res.zncc < 0.5:
            return None
        return np.array([res.x + res.sub_dx, res.y + res.sub_dy]) - self.template_corner + self.centre0

    def _fit_about(self, image: np.ndarray, centre: np.ndarray) -> OutlineFit | None:
        """The sector fits and the circle about ``centre``, again about the fitted centre until it moves less
        than :data:`FIXED_POINT_TOL_PX`: the sectors are then cut about the centre they find, as in the
        reference, so an edge that is not exactly an erf (a real ball's) biases both frames alike."""
        fit = None
        for _ in range(FIXED_POINT_PASSES):
            fit = fit_outline(image, centre, self.radius0, self.n_sectors, self.band_px,
                              reference=self.reference_fit.sectors if hasattr(self, "reference_fit") else None,
                              blur0_px=getattr(self, "blur0", 1.0))
            if fit is None:
                return None
            moved = float(np.hypot(*(fit.circle.centre - centre)))
            centre = fit.circle.centre.copy()
            if moved < FIXED_POINT_TOL_PX:
                break
        return fit

    def lost(self, reason: str) -> OutlineResult:
        return OutlineResult(name=self.name, u_px=np.full(2, np.nan), valid=0, zncc=math.nan, lost=True, reason=reason)

    def track(self, image: np.ndarray, k: int) -> OutlineResult:
        """Track the outline in ``image`` (2-D float32) of frame index ``k``."""
        img = np.asarray(image, dtype=np.float32)
        centre = None
        if self.history:
            pred = self.centre0 + self.predict(k)
            reach = DEFAULT_REACH_PX + 2.0 * self._speed() * max(k - self.history[-1][0], 1)
            for r in (reach, WIDE_REACH_FACTOR * reach):
                if not self._inside(pred, self.radius0 + r, 0.0):
                    break
                centre = self._coarse(img, pred, min(r, 0.6 * self.radius0))
                if centre is not None:
                    break
        if centre is None:
            found = self._search(img, k)
            if found is not None and self._inside(found, self.radius0, self.band_px):
                centre = self._coarse(img, found, DEFAULT_REACH_PX)
        if centre is None:
            return self.lost(f"{self.name}: no outline of radius {self.radius0:.1f} px found near the prediction "
                             "or by the search (or it leaves the image)")
        if not self._inside(centre, self.radius0, self.band_px):
            return self.lost(f"{self.name}: the outline leaves the image (centre {centre.round(1).tolist()} px, "
                             f"radius {self.radius0:.1f} px)")
        fit = self._fit_about(img, centre)
        kept = 0 if fit is None else int(np.count_nonzero(fit.circle.kept))
        if fit is None or kept < self.min_valid:
            return self.lost(f"{self.name}: too few outline sectors fitted ({kept} of {self.n_sectors}, need "
                             f"{self.min_valid}): occluded or out of focus")
        u = fit.circle.centre - self.centre0
        sig = math.sqrt(2.0) * fit.circle.sigma_px[:2]
        zn = fit.sectors.zncc
        out = OutlineResult(name=self.name, u_px=u, valid=kept, zncc=float(np.mean(zn[fit.circle.kept])), lost=False,
                            reason="",
                            point_u_px=np.broadcast_to(u, (self.n_sectors, 2)).copy(), point_valid=fit.circle.kept,
                            point_zncc=zn, sigma_px=sig, radius_px=fit.circle.radius_px,
                            radius_sigma_px=float(fit.circle.sigma_px[2]), fit=fit)
        self.history.append((k, u.copy()))
        return out


# ------------------------------------------------------------------------------- accuracy before tracking
@dataclass(kw_only=True)
class OutlineTexture:
    """The outline check of the ball before tracking (module doc), in the texture report's terms
    (:class:`~vibro_dic.texture.BodyTexture`): ``points`` one per sector, ``usable`` the sectors fitted and not
    occluded, ``mesh_sigma_px`` (2,) the predicted displacement sigma (x, y), ``variance`` twice each
    sector's gray-level variance (the pixels are matched to a noise-free model, where 1 - ZNCC = noise^2 / 2V,
    so the correlation quality's (1 - ZNCC) x variance reads the image noise, as for two noisy subsets)."""

    name: str
    roi: Roi
    points: np.ndarray
    usable: np.ndarray
    min_usable: int
    max_sigma_px: float
    noise_gray: float
    centre_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    radius_px: float = math.nan
    contrast_gray: float = math.nan
    blur_px: float = math.nan
    edge_sigma_px: float = math.nan  # median edge sigma of one sector (px)
    mesh_sigma_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    variance: np.ndarray = field(default_factory=lambda: np.empty(0))
    failure: str | None = None  # why there is no outline at all (no disc, leaves the image)

    @property
    def n_usable(self) -> int:
        return int(np.count_nonzero(self.usable))

    @property
    def max_subset_sigma_px(self) -> float:
        """The texture report's threshold: for the outline, on the whole ball's displacement sigma (px)."""
        return self.max_sigma_px

    @property
    def weak(self) -> bool:
        return not abs(self.contrast_gray) >= MIN_CONTRAST_TO_NOISE * self.noise_gray

    @property
    def refused(self) -> bool:
        worst = float(np.max(self.mesh_sigma_px)) if np.all(np.isfinite(self.mesh_sigma_px)) else math.inf
        return (self.failure is not None or self.n_usable < self.min_usable or self.weak
                or not worst <= self.max_sigma_px)

    def _numbers(self) -> str:
        return (f"outline of radius {self.radius_px:.2f} px, contrast {self.contrast_gray:.4g} gray levels against "
                f"the image noise of {self.noise_gray:.3g} ({abs(self.contrast_gray) / self.noise_gray:.3g}x; "
                f"{MIN_CONTRAST_TO_NOISE:g}x needed), edge blur sigma {self.blur_px:.2f} px, {self.n_usable} of "
                f"{len(self.points)} sectors usable (the tracker needs {self.min_usable}), edge sigma per sector "
                f"{self.edge_sigma_px:.3g} px -> predicted displacement sigma {_fmt(self.mesh_sigma_px[0])} (x), "
                f"{_fmt(self.mesh_sigma_px[1])} (y); at most {self.max_sigma_px:g} px")

    def problem(self, noise=None) -> str | None:
        """One line with the numbers when the outline is refused or some sectors are occluded; else None."""
        where = f"dic.{self.name}_roi {self.roi.as_list()} (ball_method outline)"
        if self.failure is not None:
            return f"{where}: {self.failure}"
        if self.refused:
            return (f"{where}: {self._numbers()}: light the ball so that its outline is sharp and contrasted "
                    "(backlight), or speckle it (docs/real-footage.md)")
        if self.n_usable < len(self.points):
            return (f"{where}: {len(self.points) - self.n_usable} sectors occluded or unfitted in frame 0; "
                    f"{self._numbers()}")
        return None

    def sigma_problem(self) -> str | None:
        m = self.mesh_sigma_px
        if np.all(np.isfinite(m)) and np.all(m > 0):
            return None
        return f"dic.{self.name}_roi {self.roi.as_list()}: predicted outline sigma {[float(v) for v in m]} px"

    def describe(self) -> str:
        return self._numbers()

    def to_dict(self) -> dict:
        def num(v):
            return None if v is None or not math.isfinite(float(v)) else float(v)

        return {"method": "outline", "roi": self.roi.as_list(), "n_subsets": len(self.points),
                "n_usable": self.n_usable, "min_usable": self.min_usable, "failure": self.failure,
                "centre_px": [num(v) for v in self.centre_px], "radius_px": num(self.radius_px),
                "contrast_gray": num(self.contrast_gray), "blur_px": num(self.blur_px),
                "edge_sigma_px": num(self.edge_sigma_px), "noise_gray": num(self.noise_gray),
                "mesh_sigma_px": [num(v) for v in self.mesh_sigma_px], "max_sigma_px": self.max_sigma_px}


def _fmt(v: float) -> str:
    return "inf" if not math.isfinite(v) else f"{v:.3g} px"


def assess_outline(name: str, reference: np.ndarray, roi: Roi, noise_gray: float, *,
                   max_sigma_px: float = DEFAULT_MAX_OUTLINE_SIGMA_PX,
                   min_valid_fraction: float = 0.5) -> OutlineTexture:
    """The outline check of ``roi`` in ``reference`` against the image noise ``noise_gray`` (module doc)."""
    try:
        tracker = OutlineTracker(name, reference, roi, min_valid_fraction=min_valid_fraction)
    except OutlineError as exc:
        return OutlineTexture(name=name, roi=roi, points=np.empty((0, 2)), usable=np.empty(0, bool), min_usable=1,
                              max_sigma_px=max_sigma_px, noise_gray=noise_gray,
                              failure=str(exc).split(": ", 1)[-1])
    fit = tracker.reference_fit
    sec = fit.sectors
    # a sector the edge model explains worse than the noise (a real ball's refraction, a clipped backlight)
    # counts its misfit as noise: it moves with the sampling of the edge from frame to frame
    sigma_e = sec.crb_unit * np.maximum(noise_gray, sec.residual_std)
    circle = fit_circle(sec.centre[None, :] + sec.edge_px[:, None] * sec.direction, sigma_e,
                        fit.usable, fit.circle.centre, fit.circle.radius_px)
    usable = fit.usable & (fit.circle.kept if circle is None else circle.kept)
    sig = np.full(2, np.inf) if circle is None else math.sqrt(2.0) * circle.sigma_pred_px[:2]
    return OutlineTexture(
        name=name, roi=roi, points=tracker.points, usable=usable, min_usable=tracker.min_valid,
        max_sigma_px=max_sigma_px, noise_gray=noise_gray,
        centre_px=tracker.centre0, radius_px=tracker.radius0,
        contrast_gray=float(np.median(sec.contrast[usable])) if usable.any() else math.nan,
        blur_px=float(np.median(sec.blur_px[usable])) if usable.any() else math.nan,
        edge_sigma_px=float(np.median(sigma_e[usable])) if usable.any() else math.nan,
        mesh_sigma_px=sig, variance=2.0 * sec.variance)
