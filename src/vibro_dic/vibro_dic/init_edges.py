"""Sub-pixel edges of textured regions (``vibro init``): the ball's circle and the plates' rows.

A speckled ball or plate is told from its surroundings by its texture, not by its mean gray level
(a speckled disc can have the background's mean). The texture is measured by the intensity
gradient component ALONG the edge (tangential for the ball's circle, horizontal for a plate's
row): the edge's own step has no gradient along it, so this amplitude is the texture's alone,

    a(p) = e0 + c (1 + s (p - E)) Phi(side (E - p) / sigma),

``p`` the position across the edge (radius or row, px), ``E`` the edge (where the region's opacity
is one half), ``sigma`` the edge blur (optics, px; one value for the ball and both plates: same
lens, same focus), ``c`` the texture's amplitude inside with a linear trend ``s`` (shading),
``e0`` the floor outside (noise, background). The profile is the mean amplitude over the whole
ring (ball) or row (plate), fitted by least squares.

How sure: a speckle pattern is random, so the edge found from one image scatters about the true
edge by an amount set by the texture near it (the texture's realisation, not the read noise: a
noise-free image scatters as much). It is measured from the image itself: the edge is also fitted
on independent pieces (angular sectors of the ring, column blocks of a row), and the scatter of
those over the square root of their number is the whole edge's 1-sigma uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import ndtr

RING_HALF_WIDTH_PX = 12.0   # the profile spans the edge +- this (px)
BIN_PX = 0.5
N_BALL_SECTORS = 16
N_PLATE_BLOCKS = 8
MIN_SIGMA_PX, MAX_SIGMA_PX = 0.4, 6.0


def gradients_xy(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d/dx, d/dy) of ``image`` (gray levels per px): Sobel divided by 8 (a unit-slope ramp gives 1)."""
    import cv2

    img = image.astype(np.float32)
    return (cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0, cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0)


def binned_mean(pos: np.ndarray, value: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bin centres, mean of ``value`` per bin, count per bin) for positions in [lo, hi) in BIN_PX bins;
    empty bins dropped."""
    edges = np.arange(lo, hi + 1e-9, BIN_PX)
    idx = np.floor((pos - lo) / BIN_PX).astype(int)
    ok = (idx >= 0) & (idx < edges.size - 1)
    n = np.bincount(idx[ok], minlength=edges.size - 1)
    s = np.bincount(idx[ok], value[ok], minlength=edges.size - 1)
    keep = n > 0
    return (0.5 * (edges[1:] + edges[:-1]))[keep], s[keep] / n[keep], n[keep]


@dataclass
class EdgeFit:
    """One textured edge: position ``edge_px`` (radius or row), the blur ``sigma_px``, the texture's
    amplitude inside ``contrast`` and the floor outside ``floor`` (gray levels per px)."""

    edge_px: float
    sigma_px: float
    contrast: float
    floor: float
    ok: bool


def _linear_part(pos: np.ndarray, amp: np.ndarray, edge: float, side: float, sigma_px: float
                 ) -> tuple[float, np.ndarray]:
    """(residual sum of squares, (e0, c, c s)) of the model at fixed edge and blur: linear in the rest."""
    step = ndtr(side * (edge - pos) / sigma_px)
    basis = np.column_stack([np.ones_like(pos), step, (pos - edge) * step])
    coef, *_ = np.linalg.lstsq(basis, amp, rcond=None)
    r = basis @ coef - amp
    return float(r @ r), coef


def _rss_grid(pos: np.ndarray, amp: np.ndarray, edges: np.ndarray, side: float, sigma_px: float) -> np.ndarray:
    """:func:`_linear_part`'s residual sum of squares for every edge in ``edges`` at once (normal equations)."""
    step = ndtr(side * (edges[:, None] - pos[None, :]) / sigma_px)                  # (n_edges, n_pos)
    basis = np.stack([np.ones_like(step), step, (pos[None, :] - edges[:, None]) * step], axis=2)
    gram = np.einsum("epi,epj->eij", basis, basis) + 1e-9 * np.eye(3)
    rhs = np.einsum("epi,p->ei", basis, amp)
    coef = np.linalg.solve(gram, rhs[:, :, None])[:, :, 0]
    return float(amp @ amp) - np.einsum("ei,ei->e", coef, rhs)


def _best_edge(pos: np.ndarray, amp: np.ndarray, side: float, sigma_px: float) -> tuple[float, float]:
    """(edge px, residual sum of squares) at blur ``sigma_px``: a 0.25 px grid, then Brent's method
    within one grid step of the grid's best."""
    lo, hi = pos.min() + 2.0, pos.max() - 2.0
    grid = np.arange(lo, hi + 1e-9, 0.25)
    k = int(np.argmin(_rss_grid(pos, amp, grid, side, sigma_px)))
    got = minimize_scalar(lambda e: _linear_part(pos, amp, e, side, sigma_px)[0], method="bounded",
                          bounds=(max(grid[k] - 0.25, lo), min(grid[k] + 0.25, hi)), options={"xatol": 1e-4})
    return float(got.x), float(got.fun)


def fit_edge(pos: np.ndarray, amp: np.ndarray, guess_px: float, side: float, sigma_px: float | None = None) -> EdgeFit:
    """Least-squares fit of the module's edge model to a mean-amplitude profile (position ``pos`` px).

    ``side`` +1: the texture lies at positions below the edge (inside a ring, above a plate's lower
    edge); -1: above it. ``sigma_px`` None: the blur is fitted too. The model is linear in its levels,
    so only the edge (and blur) are searched. ``ok`` False when the fit has no contrast or sits at the
    profile's end."""
    if pos.size < 12:
        return EdgeFit(guess_px, math.nan, 0.0, 0.0, False)
    if sigma_px is None:
        got = minimize_scalar(lambda sg: _best_edge(pos, amp, side, sg)[1], method="bounded",
                              bounds=(MIN_SIGMA_PX, MAX_SIGMA_PX), options={"xatol": 1e-3})
        sig = float(got.x)
    else:
        sig = sigma_px
    edge, _ = _best_edge(pos, amp, side, sig)
    _, (e0, c, _) = _linear_part(pos, amp, edge, side, sig)
    ok = c > 0 and pos.min() + 2.5 < edge < pos.max() - 2.5 and MIN_SIGMA_PX + 1e-3 < sig < MAX_SIGMA_PX - 1e-3
    return EdgeFit(edge, sig, float(c), float(e0), bool(ok))


# ------------------------------------------------------------------------------------------------ ball

def ring_amplitude(gx: np.ndarray, gy: np.ndarray, cx: float, cy: float, r0: float,
                   allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(radius, angle, |tangential gradient|) of the pixels within RING_HALF_WIDTH_PX of the circle
    (cx, cy, r0) (px; angle in rad, atan2 of rows down), only where ``allowed`` (e.g. not on a plate)."""
    h, w = gx.shape
    half = RING_HALF_WIDTH_PX + 1
    x0, x1 = max(int(cx - r0 - half), 0), min(int(cx + r0 + half) + 2, w)
    y0, y1 = max(int(cy - r0 - half), 0), min(int(cy + r0 + half) + 2, h)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    dx, dy = xx - cx, yy - cy
    r = np.hypot(dx, dy)
    sel = np.abs(r - r0) < half
    if allowed is not None:
        sel &= allowed[y0:y1, x0:x1]
    r, dx, dy = r[sel], dx[sel], dy[sel]
    amp = np.abs(-dy * gx[y0:y1, x0:x1][sel] + dx * gy[y0:y1, x0:x1][sel]) / np.maximum(r, 1e-9)
    return r, np.arctan2(dy, dx), amp


def fit_ring(gx: np.ndarray, gy: np.ndarray, cx: float, cy: float, r0: float, sigma_px: float | None,
             allowed: np.ndarray | None = None) -> EdgeFit:
    """The textured disc's edge radius about (cx, cy) from the whole ring's mean tangential amplitude."""
    r, _, amp = ring_amplitude(gx, gy, cx, cy, r0, allowed)
    pos, mean, _ = binned_mean(r, amp, r0 - RING_HALF_WIDTH_PX, r0 + RING_HALF_WIDTH_PX)
    return fit_edge(pos, mean, r0, +1.0, sigma_px)


def sector_edges(gx: np.ndarray, gy: np.ndarray, cx: float, cy: float, r0: float, sigma_px: float,
                 allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(sector mid-angles, edge radii; NaN where the fit fails or the sector is mostly not ``allowed``)
    on N_BALL_SECTORS independent sectors."""
    r, ang, amp = ring_amplitude(gx, gy, cx, cy, r0, allowed)
    sector = np.floor((ang + math.pi) / (2 * math.pi) * N_BALL_SECTORS).astype(int) % N_BALL_SECTORS
    mids = -math.pi + (np.arange(N_BALL_SECTORS) + 0.5) * 2 * math.pi / N_BALL_SECTORS
    radii = np.full(N_BALL_SECTORS, np.nan)
    for k in range(N_BALL_SECTORS):
        m = sector == k
        if m.sum() < 0.5 * 2 * math.pi * r0 / N_BALL_SECTORS * 2 * RING_HALF_WIDTH_PX:
            continue
        pos, mean, _ = binned_mean(r[m], amp[m], r0 - RING_HALF_WIDTH_PX, r0 + RING_HALF_WIDTH_PX)
        f = fit_edge(pos, mean, r0, +1.0, sigma_px)
        if f.ok:
            radii[k] = f.edge_px
    return mids, radii


def fit_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Algebraic (Kasa) least-squares circle through points: (cx, cy, r) px."""
    a = np.column_stack([x, y, np.ones_like(x)])
    (p, q, c), *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
    cx, cy = p / 2.0, q / 2.0
    return float(cx), float(cy), float(math.sqrt(max(c + cx * cx + cy * cy, 0.0)))


# ---------------------------------------------------------------------------------------------- plates

def row_amplitude(gx: np.ndarray, mask: np.ndarray, rows: slice, cols: np.ndarray | slice = slice(None)
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(row indices, mean |d/dx| over the unmasked pixels of each row) in ``rows`` x ``cols``."""
    a = np.abs(gx[rows][:, cols]).astype(np.float64)
    m = mask[rows][:, cols]
    n = m.sum(axis=1)
    idx = np.arange(gx.shape[0])[rows]
    keep = n > 0
    return idx[keep].astype(float), (np.where(m, a, 0.0).sum(axis=1)[keep] / n[keep])


def fit_plate_edge(gx: np.ndarray, mask: np.ndarray, guess_row: float, side: float, sigma_px: float | None,
                   cols: np.ndarray | slice = slice(None)) -> EdgeFit:
    """A plate's cavity edge (row, px) from the mean horizontal-gradient amplitude of each row in ``cols``
    (``mask`` False: pixels left out, e.g. the ball). ``side`` +1 for the top plate (texture above the
    edge, rows < edge), -1 for the bottom plate."""
    h = gx.shape[0]
    lo = max(int(math.floor(guess_row - RING_HALF_WIDTH_PX)), 0)
    hi = min(int(math.ceil(guess_row + RING_HALF_WIDTH_PX)) + 1, h)
    pos, mean = row_amplitude(gx, mask, slice(lo, hi), cols)
    return fit_edge(pos, mean, guess_row, side, sigma_px)
