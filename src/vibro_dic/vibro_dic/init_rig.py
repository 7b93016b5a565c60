"""``vibro init``'s measurements: find the ball, the two plates and a textured structure patch in a video.

Pixel convention as everywhere (:mod:`vibro_dic.mesh`): x = column, y = row, rows grow downwards.
Gray levels are those of an 8-bit image (16-bit frames are divided by 257).

What is measured on frame 0 (and how sure it is), see :mod:`vibro_dic.init_edges`:

- the ball: a textured disc (cv2.HoughCircles on the texture energy), its edge located on the texture
  ALONG the edge (tangential gradient amplitude; the edge's own step has none): the centre from a
  robust circle fit through the edges of angular sectors, the radius from the whole ring's profile,
  its 1-sigma from the sectors' scatter;
- the plates: the same on the rows (horizontal gradient amplitude), the row from the whole width,
  its 1-sigma from column blocks, whose line must be horizontal (a plate edge, not a tilted camera);
- the edge blur: one value for the three edges (same lens, same focus);
- the motion over the first frames (template matching, sub-pixel): the plates must move (the drive
  is on) and the ball must move relative to them (a free ball, not a mark on the structure).

Two scales follow from the two known lengths: the ball's diameter over its fitted diameter in pixels,
and the gap over the plates' distance. They must agree within what the localisation allows
(:func:`scale_tolerance`), else the setup is refused; the scale written is their inverse-variance
mean (a speckled edge's position scatters with the speckle's realisation, and the gap, 3 to 4 ball
diameters long, is the relatively more accurate length).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from vibro_io.rig import Roi
from vibro_model.errors import RecordingError

from . import init_edges as edges
from . import outline
from .icgn import gradients
from .mesh import mesh_points
from .noise import cramer_rao_px
from .outline import OutlineTexture

EDGE_SYSTEMATIC_PX = 0.25     # allowed model error of one edge position beyond its statistical error (px)
EDGE_STD_FLOOR_PX = 0.05      # an edge's stated 1-sigma is never below this (px)
EDGE_MARGIN_PX = 6            # ROIs keep this far inside the ball's / plate's edge (edge blur + fit error)
MIN_PLATE_STRENGTH = 5.0     # a plate's texture step over the row profile's robust noise
MAX_PLATE_TILT_PX = 2.0       # the plate edge's rise across the image beyond which it is not a plate
MIN_STRUCTURE_MOTION_PX = 0.5
MIN_BALL_RELATIVE_MOTION_PX = 2.0
#: a subset whose Cramer-Rao displacement std (px) exceeds this has too little texture for DIC
MAX_SUBSET_CRAMER_RAO_PX = 0.02
IMAGE_EDGE_MARGIN_PX = 2


class InitError(RecordingError):
    """``vibro init`` cannot set the rig up from this video: what is missing, with the numbers."""


def to_gray255(image: np.ndarray) -> np.ndarray:
    """float32 image in 8-bit gray levels (uint16 frames are divided by 257)."""
    img = image.astype(np.float32)
    return img / 257.0 if image.dtype == np.uint16 else img


@dataclass(kw_only=True)
class Ball:
    """The ball in frame 0: centre (x, y) px, radius px, and the 1-sigma uncertainty of the radius (px).
    ``method`` "mesh": a speckled ball (DIC subsets inside it); "outline": a plain disc found by its
    silhouette and fitted by :mod:`vibro_dic.outline` (``n_sectors`` sectors tried, ``n_edge_points`` kept,
    ``blur_px`` the outline's edge sigma)."""

    x_px: float
    y_px: float
    radius_px: float
    radius_std_px: float
    n_edge_points: int
    edge_residual_px: float
    method: str = "mesh"
    n_sectors: int = 0
    blur_px: float = math.nan
    fit_radius_std_px: float = math.nan  # outline: the circle fit's own 1-sigma (radius_std_px is floored)

    def describe(self) -> str:
        """One phrase naming the ball found (for messages)."""
        kind = "a plain ball (by its outline)" if self.method == "outline" else "a speckled ball"
        return f"{kind} at ({self.x_px:.2f}, {self.y_px:.2f}) px, radius {self.radius_px:.2f} px"


@dataclass
class Plates:
    """Rows (px, sub-pixel) of the cavity's top and bottom edges in frame 0, with 1-sigma uncertainties."""

    top_row_px: float
    bottom_row_px: float
    top_std_px: float
    bottom_std_px: float

    @property
    def gap_px(self) -> float:
        return self.bottom_row_px - self.top_row_px

    @property
    def gap_std_px(self) -> float:
        return math.hypot(self.top_std_px, self.bottom_std_px)


@dataclass
class Motion:
    """Displacements (px, rows, positive DOWN) from frame 0 over the frames examined."""

    frames: np.ndarray            # frame indices
    structure_down_px: np.ndarray
    ball_down_px: np.ndarray      # NaN beyond the frames the ball was followed on

    @property
    def structure_range_px(self) -> tuple[float, float]:
        return float(np.min(self.structure_down_px)), float(np.max(self.structure_down_px))

    @property
    def ball_relative_range_px(self) -> float:
        rel = self.ball_down_px - self.structure_down_px
        rel = rel[np.isfinite(rel)]
        return float(np.ptp(rel)) if rel.size else 0.0


@dataclass
class Scale:
    """mm/px from the ball's diameter and from the gap, their uncertainties and the allowed disagreement."""

    from_ball: float
    from_gap: float
    ball_rel_std: float
    gap_rel_std: float
    tolerance_rel: float

    @property
    def disagreement_rel(self) -> float:
        return self.from_gap / self.from_ball - 1.0

    @property
    def ball_weight(self) -> float:
        """The ball's share of the inverse-variance mean (the gap has 1 - this)."""
        wb, wg = self.ball_rel_std ** -2, self.gap_rel_std ** -2
        return wb / (wb + wg)

    @property
    def mm_per_px(self) -> float:
        """The scale written: the inverse-variance mean of the two (mm/px)."""
        return self.ball_weight * self.from_ball + (1.0 - self.ball_weight) * self.from_gap

    @property
    def rel_std(self) -> float:
        """1-sigma of :attr:`mm_per_px`, relative."""
        return (self.ball_rel_std ** -2 + self.gap_rel_std ** -2) ** -0.5


@dataclass(kw_only=True)
class Proposal:
    """Everything ``vibro init`` found and proposes."""

    width_px: int
    height_px: int
    ball: Ball
    plates: Plates
    motion: Motion
    scale: Scale
    ball_roi: Roi
    structure_roi: Roi
    structure_plate: str            # "top" or "bottom"
    subset_px: int
    mesh_step_px: int
    noise_gray: float
    edge_sigma_px: float            # the edges' blur (ball and plates)
    ball_cramer_rao_px: float       # worst subset of the ball ROI (NaN for a ball tracked by its outline)
    structure_cramer_rao_px: float  # worst subset of the structure ROI
    frequency_hz: float | None = None
    frequency_note: str = ""
    notes: list[str] = field(default_factory=list)
    #: a plain ball: the outline check of ``ball_roi`` (:func:`vibro_dic.outline.assess_outline`), else None
    ball_outline: OutlineTexture | None = None

    @property
    def ball_method(self) -> str:
        return self.ball.method


# ----------------------------------------------------------------------------------------------- ball

def _hough_candidates(blurred: np.ndarray, max_n: int = 8) -> list[tuple[float, float, float]]:
    """Up to ``max_n`` (x, y, r) circle candidates from cv2.HoughCircles on the blurred image: the strongest
    first, from a strict accumulator threshold down to a lax one (a strong circle elsewhere, e.g. at a
    plate's corner, must not hide the ball)."""
    h, w = blurred.shape
    lo, hi = float(np.percentile(blurred, 1)), float(np.percentile(blurred, 99))
    img8 = np.clip((blurred - lo) * 255.0 / max(hi - lo, 1e-6), 0, 255).astype(np.uint8)
    max_r = int(min(h, w) // 2)
    out: list[tuple[float, float, float]] = []
    for accumulator in (40, 30, 22, 16):
        circles = cv2.HoughCircles(img8, cv2.HOUGH_GRADIENT, dp=1, minDist=max(8, max_r // 2), param1=60,
                                   param2=accumulator, minRadius=6, maxRadius=max_r)
        for c in ([] if circles is None else circles[0]):
            x, y, r = map(float, c)
            if all(math.hypot(x - a, y - b) > 0.5 * min(r, q) for a, b, q in out):
                out.append((x, y, r))
        if len(out) >= max_n:
            break
    return out[:max_n]


def _coarse_radius(feature: np.ndarray, x0: float, y0: float, r0: float) -> float | None:
    """Radius (px) where the median-over-angles radial profile of ``feature`` (the log texture energy)
    first crosses half-way from its inner (0.2..0.5 r0) to its outer (1.5..1.8 r0) level; None without
    such a crossing."""
    ang = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)
    radii = np.arange(0.2 * r0, 1.8 * r0, 0.25)
    xs = x0 + np.cos(ang)[:, None] * radii[None, :]
    ys = y0 + np.sin(ang)[:, None] * radii[None, :]
    prof = np.median(map_coordinates(feature, [ys.ravel(), xs.ravel()], order=1, mode="nearest").reshape(xs.shape),
                     axis=0)
    lv_in, lv_out = prof[radii <= 0.5 * r0].mean(), prof[radii >= 1.5 * r0].mean()
    if not lv_in > lv_out + math.log(4.0):  # a textured disc: much more texture inside than around it
        return None
    below = np.nonzero(prof < 0.5 * (lv_in + lv_out))[0]
    below = below[radii[below] > 0.5 * r0]
    return float(radii[below[0]]) if below.size else None


def _coarse_circle(energy: np.ndarray, x0: float, y0: float, r0: float) -> tuple[float, float, float] | None:
    """(cx, cy, r) px of the textured blob around a Hough candidate: the connected region of ``energy``
    above half-way between the candidate's inner and outer levels (:func:`_coarse_radius`), its centroid
    and the radius of its area. None without a textured disc there; the Hough circle itself when the
    blob runs into something else (a plate)."""
    r1 = _coarse_radius(energy, x0, y0, r0)
    if r1 is None:
        return None
    ang = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)
    inner = map_coordinates(energy, [y0 + 0.35 * r1 * np.sin(ang), x0 + 0.35 * r1 * np.cos(ang)], order=1,
                            mode="nearest")
    outer = map_coordinates(energy, [y0 + 1.6 * r1 * np.sin(ang), x0 + 1.6 * r1 * np.cos(ang)], order=1,
                            mode="nearest")
    level = 0.5 * (np.median(inner) + np.median(outer))
    from scipy.ndimage import binary_fill_holes

    blob = binary_fill_holes(cv2.morphologyEx((energy > level).astype(np.uint8), cv2.MORPH_CLOSE,
                                              cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))))
    n, labels = cv2.connectedComponents(blob.astype(np.uint8), connectivity=8)
    lab = labels[int(np.clip(round(y0), 0, energy.shape[0] - 1)), int(np.clip(round(x0), 0, energy.shape[1] - 1))]
    if lab == 0:
        return x0, y0, r1
    ys, xs = np.nonzero(labels == lab)
    area = float(xs.size)
    if area > 2.0 * math.pi * r1 * r1:
        return x0, y0, r1
    return float(xs.mean()), float(ys.mean()), math.sqrt(area / math.pi)


def texture_energy(frame: np.ndarray, sigma_px: float = 2.0) -> np.ndarray:
    """Local texture energy: squared intensity gradient (Sobel) averaged by a Gaussian of ``sigma_px``."""
    gx = cv2.Sobel(frame, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(frame, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.GaussianBlur(gx * gx + gy * gy, (0, 0), sigma_px)


MIN_CLEAN_SECTORS = edges.N_BALL_SECTORS // 2


def refine_ball(gx: np.ndarray, gy: np.ndarray, x0: float, y0: float, r0: float, sigma_px: float | None,
                allowed: np.ndarray | None = None) -> tuple[Ball, float] | None:
    """(the textured disc's circle, the edge blur sigma px) near (x0, y0, r0): the centre from a robust
    circle fit through the edges of N_BALL_SECTORS sectors, the radius from the whole ring's profile
    (:mod:`vibro_dic.init_edges`), both on the ``allowed`` pixels only (not on a plate). ``sigma_px``
    None: fitted on the ring. None when fewer than MIN_CLEAN_SECTORS sectors show a clean edge."""
    cx, cy, r = x0, y0, r0
    sig = sigma_px
    for _ in range(3):
        ring = edges.fit_ring(gx, gy, cx, cy, r, sigma_px, allowed)
        if not ring.ok:
            return None
        r, sig = ring.edge_px, ring.sigma_px
        mids, radii = edges.sector_edges(gx, gy, cx, cy, r, sig, allowed)
        ok = np.isfinite(radii)
        if ok.sum() < MIN_CLEAN_SECTORS:
            return None
        ex, ey = cx + np.cos(mids[ok]) * radii[ok], cy + np.sin(mids[ok]) * radii[ok]
        use = np.ones(ex.size, bool)
        for _ in range(3):  # robust: drop sectors whose edge is far from the circle
            fx, fy, fr = edges.fit_circle(ex[use], ey[use])
            res = np.hypot(ex - fx, ey - fy) - fr
            mad = 1.4826 * np.median(np.abs(res[use] - np.median(res[use])))
            use = np.abs(res) <= max(3.0 * mad, 0.5)
        if use.sum() < MIN_CLEAN_SECTORS:
            return None
        cx, cy = fx, fy
    ring = edges.fit_ring(gx, gy, cx, cy, r, sig, allowed)
    if not ring.ok:
        return None
    res = np.hypot(ex[use] - cx, ey[use] - cy) - fr
    scatter = float(np.std(res, ddof=3))
    std = max(scatter / math.sqrt(use.sum() - 3), EDGE_STD_FLOOR_PX)
    return Ball(x_px=cx, y_px=cy, radius_px=ring.edge_px, radius_std_px=std, n_edge_points=int(use.sum()),
                edge_residual_px=scatter), sig


def cavity_pixels(shape: tuple[int, int], top_row_px: float, bottom_row_px: float) -> np.ndarray:
    """True on the rows between two plate edges, EDGE_MARGIN_PX clear of each (no plate texture)."""
    rows = np.arange(shape[0])
    inside = (rows > top_row_px + EDGE_MARGIN_PX) & (rows < bottom_row_px - EDGE_MARGIN_PX)
    return np.broadcast_to(inside[:, None], shape)


def find_ball(frame0: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> tuple[Ball, float]:
    """(the ball in frame 0, its edge blur sigma px): a textured disc between two textured plates.
    Candidates from cv2.HoughCircles on the log texture energy; each is refined by :func:`refine_ball`
    on the pixels between the plates found around it; the candidate with the most clean sectors and
    the least scatter wins. InitError if no circle with a clean edge is found."""
    energy = np.log(texture_energy(frame0, 3.0) + 1.0)
    found: list[tuple[Ball, float]] = []
    for x, y, r in _hough_candidates(energy):
        coarse = _coarse_circle(energy, x, y, r)
        if coarse is None or coarse[2] < 8:
            continue
        allowed = None
        top, bottom, strength = plate_guesses(gx,
                                              Ball(x_px=coarse[0], y_px=coarse[1], radius_px=coarse[2],
                                                   radius_std_px=math.nan, n_edge_points=0, edge_residual_px=math.nan))
        if strength >= MIN_PLATE_STRENGTH:
            allowed = cavity_pixels(gx.shape, top, bottom)
        got = refine_ball(gx, gy, *coarse, None, allowed)
        if got is not None and got[0].radius_px >= 8:
            found.append(got)
    if not found:
        plain, why_not = find_plain_ball(frame0)
        if plain is not None:
            return plain
        raise InitError("no ball found in frame 0: no textured disc with a clean edge on "
                        f">= {MIN_CLEAN_SECTORS} of {edges.N_BALL_SECTORS} sectors (cv2.HoughCircles on the texture "
                        f"energy, refined on the texture along the edge), and no plain disc with a clean outline "
                        f"({why_not}); is the ball in view and in focus, speckled or backlit?")
    return min(found, key=lambda b: (-b[0].n_edge_points, b[0].edge_residual_px))


# ------------------------------------------------------------------------------------------ plain ball
MIN_PLAIN_RADIUS_PX = 8.0
#: the outline box reaches this far (px) beyond the ball's outline, at least (the synth's and the docs' box)
OUTLINE_ROI_MARGIN_PX = 6
#: ... and never less than this where a plate or the image border cuts it (find_disc needs background round it)
MIN_OUTLINE_ROI_MARGIN_PX = 2


def _silhouettes(frame0: np.ndarray) -> list[tuple[float, float, float]]:
    """(x, y, half the larger bounding-box side) px of the connected regions of either class of Otsu's threshold
    of frame 0 (lightly smoothed) that are large enough for a ball and do not touch the image border, holes
    filled (a highlight inside a dark ball): the candidates for a plain disc, the largest first."""
    h, w = frame0.shape
    lo, hi = float(np.percentile(frame0, 0.5)), float(np.percentile(frame0, 99.5))
    if not hi > lo:
        return []
    u8 = np.clip((frame0 - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
    _, bright = cv2.threshold(cv2.GaussianBlur(u8, (0, 0), 1.0), 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    from scipy.ndimage import binary_fill_holes

    out = []
    for fg in (bright == 0, bright == 1):
        n, _, stats, centroids = cv2.connectedComponentsWithStats(
            binary_fill_holes(fg).astype(np.uint8), connectivity=8)
        for k in range(1, n):
            x, y, bw, bh, area = (int(v) for v in stats[k])
            if x == 0 or y == 0 or x + bw >= w or y + bh >= h or area < math.pi * MIN_PLAIN_RADIUS_PX ** 2:
                continue
            out.append((float(centroids[k][0]), float(centroids[k][1]), 0.5 * max(bw, bh), area))
    return [c[:3] for c in sorted(out, key=lambda c: -c[3])]


def _box(cx: float, cy: float, half: float, width_px: int, height_px: int, rows: tuple[int, int] | None = None
         ) -> Roi:
    """The box [cx - half, cx + half] x [cy - half, cy + half] (whole pixels, inclusive of both ends), cut at the
    image and at ``rows`` (first, last allowed row)."""
    y_lo, y_hi = (0, height_px - 1) if rows is None else (max(rows[0], 0), min(rows[1], height_px - 1))
    x0, x1 = max(int(math.floor(cx - half)), 0), min(int(math.ceil(cx + half)), width_px - 1)
    y0, y1 = max(int(math.floor(cy - half)), y_lo), min(int(math.ceil(cy + half)), y_hi)
    return Roi(x0, y0, max(x1 - x0 + 1, 0), max(y1 - y0 + 1, 0))


def find_plain_ball(frame0: np.ndarray) -> tuple[tuple[Ball, float] | None, str]:
    """((the ball in frame 0, its outline's edge blur sigma px), "") for a plain ball: a dark or bright disc with a
    clean outline (:func:`vibro_dic.outline.find_disc` in a box round each silhouette of :func:`_silhouettes`,
    then the outline tracker's reference fit: sub-pixel edges of ~4 px sectors, a robust circle fit giving the
    centre, the radius and their 1-sigma from the residuals). The disc with the most sectors kept wins (at
    least half of them, what the tracker needs). (None, why) without one."""
    h, w = frame0.shape
    img = np.asarray(frame0, np.float32)
    best: tuple[Ball, float] | None = None
    tried: list[str] = []
    for x, y, half in _silhouettes(img):
        box = _box(x, y, half + OUTLINE_ROI_MARGIN_PX, w, h)
        disc = outline.find_disc(img, box)
        if disc is None or disc.radius_px < MIN_PLAIN_RADIUS_PX:
            tried.append(f"({x:.0f}, {y:.0f}): not round")
            continue
        box = _box(disc.cx, disc.cy, disc.radius_px + OUTLINE_ROI_MARGIN_PX, w, h)
        try:
            tracker = outline.OutlineTracker("ball", img, box)
        except outline.OutlineError:
            tried.append(f"({x:.0f}, {y:.0f}): no outline fit")
            continue
        fit = tracker.reference_fit
        kept = int(np.count_nonzero(fit.circle.kept))
        if kept < tracker.min_valid:
            tried.append(f"({x:.0f}, {y:.0f}): {kept} of {tracker.n_sectors} outline sectors clean")
            continue
        c = fit.circle
        res = c.residual_px[c.kept]
        # the radius's 1-sigma for the scale: the fit's, never below EDGE_STD_FLOOR_PX as for a speckled ball
        # (the edge model's own definition of the edge: a clipped backlight or a refracting ball moves the fitted
        # edge by tenths of a px against the half-level contour, ball_12bit 0.27 px, beyond the fit's sigma)
        ball = Ball(x_px=float(c.centre[0]), y_px=float(c.centre[1]), radius_px=float(c.radius_px),
                    radius_std_px=max(float(c.sigma_px[2]), EDGE_STD_FLOOR_PX), n_edge_points=kept,
                    edge_residual_px=float(np.sqrt(np.mean(res ** 2))),
                    method="outline", n_sectors=tracker.n_sectors, blur_px=float(tracker.blur0),
                    fit_radius_std_px=float(c.sigma_px[2]))
        if best is None or kept > best[0].n_edge_points:
            best = (ball, tracker.blur0)
    if best is not None:
        return best, ""
    if not tried:
        return None, "no dark or bright region of ball size clear of the image border"
    return None, "candidates " + "; ".join(tried[:4])


def propose_outline_roi(ball: Ball, plates: Plates | None, width_px: int, height_px: int) -> Roi:
    """The box around the whole plain ball in frame 0 that ``dic.ball_method: outline`` tracks from: the outline
    plus OUTLINE_ROI_MARGIN_PX, or the outline's edge band (:func:`vibro_dic.outline.band_width`) plus 1 px when
    that is wider, cut at the image and before the plates' edges; InitError when less than
    MIN_OUTLINE_ROI_MARGIN_PX of background is left on a side (the ball touches a plate or the border)."""
    margin = max(OUTLINE_ROI_MARGIN_PX, math.ceil(outline.band_width(ball.blur_px) + 1.0))
    rows = None
    if plates is not None:
        rows = (int(math.floor(plates.top_row_px)) + 1, int(math.ceil(plates.bottom_row_px)) - 1)
    roi = _box(ball.x_px, ball.y_px, ball.radius_px + margin, width_px, height_px, rows)
    left = min(ball.x_px - roi.x, roi.x + roi.w - 1 - ball.x_px, ball.y_px - roi.y,
               roi.y + roi.h - 1 - ball.y_px) - ball.radius_px
    if left < MIN_OUTLINE_ROI_MARGIN_PX:
        raise InitError(f"{ball.describe()}: its box {roi.as_list()} keeps only {left:.1f} px of background beyond "
                        f"the outline on one side (the image's border or a plate; need {MIN_OUTLINE_ROI_MARGIN_PX} "
                        "px): pick a recording whose frame 0 shows the ball clear of the plates")
    return roi


# --------------------------------------------------------------------------------------------- plates

def _edge_in(profile_grad: np.ndarray, lo: int, hi: int) -> tuple[float, float]:
    """(row of the largest |gradient| in rows [lo, hi), its |gradient|)."""
    seg = np.abs(profile_grad[lo:hi])
    if seg.size < 3:
        return math.nan, 0.0
    k = int(np.argmax(seg))
    return float(lo + k), float(seg[k])


def _smooth1d(x: np.ndarray, sigma: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(np.asarray(x, dtype=np.float64), sigma, mode="nearest")


def _outside_ball(shape: tuple[int, int], ball: Ball) -> np.ndarray:
    """True where a pixel is more than EDGE_MARGIN_PX outside the ball's circle."""
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return np.hypot(xx - ball.x_px, yy - ball.y_px) > ball.radius_px + EDGE_MARGIN_PX


def plate_guesses(gx: np.ndarray, ball: Ball) -> tuple[float, float, float]:
    """(top row, bottom row, weakest edge's strength) of the strongest steps of the row profile of the
    texture along the rows (mean |d/dx|, the ball left out) above and below the ball; the strength is
    the step over the profile's robust noise."""
    h = gx.shape[0]
    mask = _outside_ball(gx.shape, ball)
    rows, prof = edges.row_amplitude(gx, mask, slice(0, h))
    full = np.interp(np.arange(h), rows, prof)
    g = np.gradient(_smooth1d(full, 1.5))
    top_hi = int(math.floor(ball.y_px - ball.radius_px))
    bot_lo = int(math.ceil(ball.y_px + ball.radius_px)) + 1
    t0, st = _edge_in(g, 2, top_hi)
    b0, sb = _edge_in(g, bot_lo, h - 2)
    noise = 1.4826 * float(np.median(np.abs(g - np.median(g))))
    return t0, b0, min(st, sb) / max(noise, 1e-9)


def _plate_side(gx: np.ndarray, mask: np.ndarray, guess: float, side: float, sigma_px: float, name: str
                ) -> tuple[float, float]:
    """(edge row, 1-sigma px) of one plate: the whole width's profile, and the scatter over N_PLATE_BLOCKS
    column blocks (a line fit: a tilt beyond MAX_PLATE_TILT_PX plus 3 sigma is refused)."""
    w = gx.shape[1]
    whole = edges.fit_plate_edge(gx, mask, guess, side, sigma_px)
    if not whole.ok:
        raise InitError(f"plates not found in frame 0: the {name} plate's texture edge near row {guess:.0f} does "
                        "not fit a blurred step (no textured plate there?)")
    centres, rows = [], []
    for cols in np.array_split(np.arange(w), edges.N_PLATE_BLOCKS):
        f = edges.fit_plate_edge(gx, mask, whole.edge_px, side, sigma_px, cols)
        if f.ok:
            centres.append(cols.mean())
            rows.append(f.edge_px)
    n = len(rows)
    if n < edges.N_PLATE_BLOCKS // 2 + 1:
        raise InitError(f"plates not found in frame 0: the {name} plate's edge (row {whole.edge_px:.1f}) is clean "
                        f"on only {n} of {edges.N_PLATE_BLOCKS} column blocks")
    centres, rows = np.array(centres), np.array(rows)
    a = np.column_stack([centres - centres.mean(), np.ones(n)])
    coef, *_ = np.linalg.lstsq(a, rows, rcond=None)
    res = rows - a @ coef
    scatter = float(np.sqrt(np.sum(res ** 2) / max(n - 2, 1)))
    tilt_px = float(coef[0]) * (w - 1)
    tilt_std_px = scatter / math.sqrt(np.sum((centres - centres.mean()) ** 2)) * (w - 1)
    if abs(tilt_px) > MAX_PLATE_TILT_PX + 3.0 * tilt_std_px:
        raise InitError(f"plates not found in frame 0: the {name} edge rises {tilt_px:+.1f} +- {tilt_std_px:.1f} px "
                        f"across the image (a line through {n} column blocks; a plate edge is horizontal, <= "
                        f"{MAX_PLATE_TILT_PX} px): camera tilted, or not a plate")
    std = float(np.std(rows, ddof=1)) / math.sqrt(n)
    return whole.edge_px, max(std, EDGE_STD_FLOOR_PX)


def find_plates(gx: np.ndarray, ball: Ball, sigma_px: float | None) -> tuple[Plates, list[float]]:
    """(the cavity's top and bottom edges, their fitted blurs when ``sigma_px`` is None): the textured
    plates' edges above and below the ball (:mod:`vibro_dic.init_edges`), with the blur ``sigma_px``."""
    h = gx.shape[0]
    if ball.y_px - ball.radius_px < 6 or ball.y_px + ball.radius_px > h - 7:
        raise InitError(f"plates not found in frame 0: no room above or below the ball (rows "
                        f"{ball.y_px - ball.radius_px:.0f}..{ball.y_px + ball.radius_px:.0f} of {h})")
    t0, b0, strength = plate_guesses(gx, ball)
    if not strength >= MIN_PLATE_STRENGTH:
        raise InitError(f"plates not found in frame 0: the strongest texture steps above/below the ball stand only "
                        f"{strength:.1f} x the row profile's noise (need >= {MIN_PLATE_STRENGTH:g}): no textured "
                        "plates framing the cavity")
    mask = _outside_ball(gx.shape, ball)
    if sigma_px is None:
        sig = [edges.fit_plate_edge(gx, mask, t0, +1.0, None).sigma_px,
               edges.fit_plate_edge(gx, mask, b0, -1.0, None).sigma_px]
        return Plates(t0, b0, math.nan, math.nan), [s for s in sig if math.isfinite(s)]
    top, top_std = _plate_side(gx, mask, t0, +1.0, sigma_px, "top")
    bot, bot_std = _plate_side(gx, mask, b0, -1.0, sigma_px, "bottom")
    return Plates(top, bot, top_std, bot_std), []


def measure_frame0(frame0: np.ndarray) -> tuple[Ball, Plates, float]:
    """(ball, plates, edge blur sigma px) in frame 0. The blur is one value for the ball and both plates
    (same lens and focus): the median of the three edges' own fits; all edges are then fitted with it."""
    gx, gy = edges.gradients_xy(frame0)
    ball, sig_ball = find_ball(frame0, gx, gy)
    if ball.method == "outline":
        # a plain ball: fitted by its outline already (its erf blur is not the plates' texture blur)
        try:
            guess, sig_plates = find_plates(gx, ball, None)
            sigma = float(np.median(sig_plates)) if sig_plates else sig_ball
            plates, _ = find_plates(gx, ball, sigma)
        except InitError as exc:
            raise InitError(f"found {ball.describe()}, but {exc}") from None
        return ball, plates, sigma
    guess, sig_plates = find_plates(gx, ball, None)
    sigma = float(np.median([sig_ball, *sig_plates]))
    allowed = cavity_pixels(gx.shape, guess.top_row_px, guess.bottom_row_px)
    refined = refine_ball(gx, gy, ball.x_px, ball.y_px, ball.radius_px, sigma, allowed)
    if refined is None:
        raise InitError(f"no ball found in frame 0: the circle at ({ball.x_px:.1f}, {ball.y_px:.1f}) px, r "
                        f"{ball.radius_px:.1f} px loses its clean edge with the common edge blur {sigma:.2f} px")
    ball = refined[0]
    plates, _ = find_plates(gx, ball, sigma)
    return ball, plates, sigma


# --------------------------------------------------------------------------------------------- motion

def _match_rows(image: np.ndarray, template: np.ndarray, x0: int, y0: int, search_px: int,
                search_x_px: int = 0) -> tuple[float, float, float]:
    """(down px, right px, peak ZNCC) of ``template`` (top-left (x0, y0) in frame 0) in ``image``."""
    th, tw = template.shape
    h, w = image.shape
    ya, yb = max(0, y0 - search_px), min(h, y0 + th + search_px)
    xa, xb = max(0, x0 - search_x_px), min(w, x0 + tw + search_x_px)
    band = image[ya:yb, xa:xb]
    if band.shape[0] < th or band.shape[1] < tw:
        return math.nan, math.nan, 0.0
    score = cv2.matchTemplate(band, template, cv2.TM_CCOEFF_NORMED)
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    peak = float(score[iy, ix])

    def sub(c_m, c_0, c_p):
        den = c_m - 2 * c_0 + c_p
        return float(np.clip(0.5 * (c_m - c_p) / den, -0.5, 0.5)) if den < 0 else 0.0

    dy = sub(score[iy - 1, ix], peak, score[iy + 1, ix]) if 0 < iy < score.shape[0] - 1 else 0.0
    dx = sub(score[iy, ix - 1], peak, score[iy, ix + 1]) if 0 < ix < score.shape[1] - 1 else 0.0
    return ya + iy + dy - y0, xa + ix + dx - x0, peak


def structure_template(frame0: np.ndarray, plates: Plates, plate: str, rows_px: int) -> tuple[int, int, np.ndarray]:
    """(x0, y0, patch) of a strip of ``plate`` just outside the cavity, used to follow the structure."""
    h, w = frame0.shape
    if plate == "bottom":
        y0 = int(math.ceil(plates.bottom_row_px + EDGE_MARGIN_PX))
    else:
        y0 = int(math.floor(plates.top_row_px - EDGE_MARGIN_PX)) - rows_px
    y0 = int(np.clip(y0, 0, h - rows_px))
    x0 = IMAGE_EDGE_MARGIN_PX
    return x0, y0, frame0[y0:y0 + rows_px, x0:w - x0].copy()


def follow_motion(frames: list[tuple[int, np.ndarray]], ball: Ball, plates: Plates, plate: str,
                  n_ball_frames: int = 60, outline_roi: Roi | None = None) -> Motion:
    """Rows moved (down, px) by the plate strip and by the ball's inner square over ``frames``
    ((index, gray image) pairs, frame 0 first); the ball only on its first ``n_ball_frames``. A plain ball
    (``outline_roi``: its box in frame 0) is followed by its outline (:class:`vibro_dic.outline.OutlineTracker`):
    its inside holds nothing to match."""
    frame0 = frames[0][1]
    tracker = None if outline_roi is None else outline.OutlineTracker("ball", np.asarray(frame0, np.float32),
                                                                      outline_roi)
    strip_rows = 24
    sx, sy, strip = structure_template(frame0, plates, plate, strip_rows)
    half = int(max(4, math.floor((ball.radius_px - EDGE_MARGIN_PX) / math.sqrt(2))))
    bx, by = int(round(ball.x_px)) - half, int(round(ball.y_px)) - half
    ball_tpl = frame0[by:by + 2 * half + 1, bx:bx + 2 * half + 1].copy()
    search_s = int(plates.gap_px // 2)
    search_b = int(plates.gap_px)
    idx, s_down, b_down = [], [], []
    prev_s, prev_b = 0.0, 0.0
    for k, img in frames:
        idx.append(k)
        ds, _, peak_s = _match_rows(img, strip, sx, sy + int(round(prev_s)), search_s)
        ds = ds + int(round(prev_s)) if np.isfinite(ds) else math.nan
        s_down.append(ds if peak_s > 0.5 else math.nan)
        if np.isfinite(ds) and peak_s > 0.5:
            prev_s = ds
        if len(b_down) < n_ball_frames and tracker is not None:
            r = tracker.track(np.asarray(img, np.float32), int(k)) if k != frames[0][0] else None
            b_down.append(0.0 if r is None else (math.nan if r.lost else float(r.u_px[1])))
        elif len(b_down) < n_ball_frames:
            db, _, peak_b = _match_rows(img, ball_tpl, bx, by + int(round(prev_b)), min(search_b, 3 * half),
                                        search_x_px=half)
            db = db + int(round(prev_b)) if np.isfinite(db) else math.nan
            b_down.append(db if peak_b > 0.5 else math.nan)
            if np.isfinite(db) and peak_b > 0.5:
                prev_b = db
        else:
            b_down.append(math.nan)
    return Motion(np.array(idx), np.array(s_down, float), np.array(b_down, float))


def estimate_frequency_hz(motion: Motion, fps: float) -> tuple[float | None, str]:
    """Drive frequency (Hz) from a least-squares sine fit to the structure's motion, with a note; None
    (and the reason) when fewer than 1.5 cycles were seen."""
    ok = np.isfinite(motion.structure_down_px)
    t = motion.frames[ok] / fps
    y = motion.structure_down_px[ok]
    if t.size < 16:
        return None, f"only {t.size} frames followed"
    n = 8 * t.size
    spec = np.abs(np.fft.rfft((y - y.mean()) * np.hanning(y.size), n))
    freqs = np.fft.rfftfreq(n, d=(t[-1] - t[0]) / (t.size - 1))
    f0 = float(freqs[1 + int(np.argmax(spec[1:]))])
    cycles = f0 * (t[-1] - t[0])
    if cycles < 1.5:
        return None, f"the frames examined ({t.size}) hold {cycles:.1f} drive cycles (< 1.5)"
    best = (math.inf, f0)
    for f in np.linspace(0.9 * f0, 1.1 * f0, 401):
        a = np.column_stack([np.sin(2 * math.pi * f * t), np.cos(2 * math.pi * f * t), np.ones_like(t)])
        res = np.linalg.lstsq(a, y, rcond=None)[1]
        rss = float(res[0]) if res.size else math.inf
        if rss < best[0]:
            best = (rss, float(f))
    return best[1], f"sine fit to the structure's motion over {t.size} frames ({cycles:.1f} cycles)"


# ------------------------------------------------------------------------------------- noise, texture

def gray255_code(effective_bits: int | None = None) -> tuple[float, float]:
    """(one code, the brightest code) of frames with ``effective_bits`` significant bits in the 0..255 scale
    of :func:`to_gray255` (8 bits: uint8 as is; more: MSB-aligned in uint16, divided by 257). None: 8 bits."""
    n = 8 if effective_bits is None else int(effective_bits)
    container = 8 if n == 8 else 16
    scale = 255.0 / (2 ** container - 1)
    step = 2 ** (container - n)
    return step * scale, (2 ** container - step) * scale


def clipped_gray255(image: np.ndarray, effective_bits: int | None = None) -> np.ndarray:
    """Mask of the saturated (within half a code of the brightest) or black pixels of a :func:`to_gray255`
    frame. With ``effective_bits`` None the threshold, 254.5, also catches the brightest code of any 16-bit
    source of 9 or more effective bits (a 12-bit camera's 4095 is 254.94)."""
    code, top = gray255_code(effective_bits)
    return (image >= top - 0.5 * code) | (image <= 0.5 * code)


def noise_sigma_gray(image: np.ndarray, mask: np.ndarray | None = None, *, effective_bits: int | None = None) -> float:
    """Read-noise sigma (gray levels, 0..255 scale) by Immerkaer's Laplacian-difference estimator over ``mask``
    less the pixels next to a clipped one (:func:`clipped_gray255`: a saturated backlight has no noise to
    see), never below the quantization noise of the depth, one code / sqrt(12) (texture inflates it: an
    upper bound, hence a conservative texture check). Raises :class:`InitError` when no unclipped pixel
    is left."""
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float32)
    conv = np.abs(cv2.filter2D(image.astype(np.float32), cv2.CV_32F, kernel))[1:-1, 1:-1]
    near_clip = cv2.dilate(clipped_gray255(image, effective_bits).astype(np.uint8), np.ones((3, 3), np.uint8))
    keep = near_clip[1:-1, 1:-1] == 0
    if mask is not None:
        keep &= mask[1:-1, 1:-1]
    if not keep.any():
        raise InitError(f"no unclipped pixel to measure the image noise on ({np.mean(near_clip > 0):.0%} of frame 0 "
                        "is saturated or black, or next to such a pixel): reduce the exposure or the backlight")
    code, _ = gray255_code(effective_bits)
    return max(float(math.sqrt(math.pi / 2.0) * conv[keep].mean() / 6.0), code / math.sqrt(12.0))


def worst_cramer_rao_px(image: np.ndarray, roi: Roi, subset_px: int, step_px: int, noise_gray: float) -> float:
    """The largest Cramer-Rao displacement std (px, along rows: the motion axis) over the subsets of ``roi``."""
    _, gy = gradients(image)
    half = subset_px // 2
    worst = 0.0
    for x, y in mesh_points(roi, subset_px, step_px).astype(int):
        ssg = float(np.sum(gy[y - half:y + half + 1, x - half:x + half + 1].astype(np.float64) ** 2))
        worst = max(worst, float(cramer_rao_px(max(ssg, 1e-12), noise_gray)))
    return worst


# ------------------------------------------------------------------------------------------- scale, ROIs

def scale_tolerance(ball: Ball, plates: Plates) -> tuple[float, float, float]:
    """(ball diameter's relative std, gap's relative std, allowed relative disagreement of the two scales).

    Allowed: 3 combined sigmas plus EDGE_SYSTEMATIC_PX on each of the four edge positions (the edge
    model's own accuracy on real optics), i.e. 2 x EDGE_SYSTEMATIC_PX over the diameter and over the gap.
    """
    d_px = 2 * ball.radius_px
    ball_rel = 2 * ball.radius_std_px / d_px
    gap_rel = plates.gap_std_px / plates.gap_px
    tol = 3.0 * math.hypot(ball_rel, gap_rel) + 2 * EDGE_SYSTEMATIC_PX / d_px + 2 * EDGE_SYSTEMATIC_PX / plates.gap_px
    return ball_rel, gap_rel, tol


def propose_ball_roi(ball: Ball, subset_px: int, width_px: int, height_px: int) -> Roi:
    """The largest square centred on the ball whose corners stay EDGE_MARGIN_PX inside the fitted edge."""
    side = int(math.floor((ball.radius_px - EDGE_MARGIN_PX - 3 * ball.radius_std_px) * math.sqrt(2.0)))
    if side < subset_px:
        raise InitError(f"the ball ({2 * ball.radius_px:.1f} px across) cannot hold a {subset_px} px subset "
                        f"{EDGE_MARGIN_PX} px inside its edge (largest square {max(side, 0)} px): give a smaller "
                        "--subset-px (odd) or film the ball larger")
    x = int(round(ball.x_px - side / 2 + 0.5))
    y = int(round(ball.y_px - side / 2 + 0.5))
    if x < 0 or y < 0 or x + side > width_px or y + side > height_px:
        raise InitError(f"the ball's ROI [{x}, {y}, {side}, {side}] leaves the {width_px}x{height_px} px image")
    return Roi(x, y, side, side)


def propose_structure_roi(plates: Plates, motion: Motion, subset_px: int, step_px: int, width_px: int,
                          height_px: int) -> tuple[Roi, str]:
    """A ROI on the plate with the most room: EDGE_MARGIN_PX outside the cavity edge, subset + step rows
    high at most, inside the image for the whole travel seen (with 10 % and 2 px to spare)."""
    lo, hi = motion.structure_range_px  # rows moved down (min <= 0 <= max)
    travel_up = max(0.0, -lo) * 1.1 + IMAGE_EDGE_MARGIN_PX
    travel_down = max(0.0, hi) * 1.1 + IMAGE_EDGE_MARGIN_PX
    want_h = subset_px + step_px
    # room between the ROI's start (edge + margin) and the image border, less the travel
    start_bottom = int(math.ceil(plates.bottom_row_px + EDGE_MARGIN_PX))
    room_bottom = int(math.floor(height_px - travel_down)) - start_bottom
    end_top = int(math.floor(plates.top_row_px - EDGE_MARGIN_PX)) + 1   # exclusive
    room_top = end_top - int(math.ceil(travel_up))
    if max(room_bottom, room_top) < subset_px:
        raise InitError(f"no textured patch of the structure fits a {subset_px} px subset: above the top plate's edge "
                        f"{max(room_top, 0)} px and below the bottom one's {max(room_bottom, 0)} px stay in the image "
                        f"over the travel seen ({-lo:.1f} px up, {hi:.1f} px down); frame more of a plate")
    x, w = 8, width_px - 16
    if w < subset_px:
        x, w = 0, width_px
    if room_bottom >= room_top:
        return Roi(x, start_bottom, w, min(want_h, room_bottom)), "bottom"
    h = min(want_h, room_top)
    return Roi(x, end_top - h, w, h), "top"


def propose(frames: list[tuple[int, np.ndarray]], *, ball_diameter_mm: float, gap_mm: float, fps: float,
            subset_px: int = 31, mesh_step_px: int = 10, effective_bits: int | None = None) -> Proposal:
    """Measure frame 0 and the motion over ``frames`` ((index, gray image) pairs, frame 0 first, in the 0..255
    scale of :func:`to_gray255`) and propose ROIs and the scale. ``effective_bits``: the frames' significant
    bits (:attr:`vibro_io.frames.FrameSequence.effective_bits`; None: 8), for the saturation and the
    quantization floor of the noise (:func:`noise_sigma_gray`). Raises :class:`InitError` naming what
    cannot be found, with numbers."""
    frame0 = frames[0][1]
    h, w = frame0.shape
    ball, plates, edge_sigma = measure_frame0(frame0)
    if (not plates.top_row_px < ball.y_px - ball.radius_px + 1
            or not ball.y_px + ball.radius_px - 1 < plates.bottom_row_px):
        raise InitError(f"the ball (rows {ball.y_px - ball.radius_px:.1f}..{ball.y_px + ball.radius_px:.1f}) is not "
                        f"between the plates found (rows {plates.top_row_px:.1f}, {plates.bottom_row_px:.1f})")
    # follow the plate with more room in the image (the ROI goes there too)
    plate = "bottom" if h - plates.bottom_row_px >= plates.top_row_px else "top"
    outline_roi = propose_outline_roi(ball, plates, w, h) if ball.method == "outline" else None
    motion = follow_motion(frames, ball, plates, plate, outline_roi=outline_roi)
    n_seen = int(np.isfinite(motion.structure_down_px).sum())
    lo, hi = motion.structure_range_px if n_seen else (0.0, 0.0)
    if n_seen < 2 or hi - lo < MIN_STRUCTURE_MOTION_PX:
        raise InitError(f"the plates do not move over frames {motion.frames[0]}..{motion.frames[-1]} (range "
                        f"{hi - lo:.2f} px < {MIN_STRUCTURE_MOTION_PX} px): shaker off, or too few frames")
    rel = motion.ball_relative_range_px
    if rel < MIN_BALL_RELATIVE_MOTION_PX:
        raise InitError(f"the circle at ({ball.x_px:.1f}, {ball.y_px:.1f}) px, r {ball.radius_px:.1f} px, moves only "
                        f"{rel:.2f} px relative to the plates over the frames followed "
                        f"(< {MIN_BALL_RELATIVE_MOTION_PX} px): not a free ball (a mark on the structure?)")
    ball_rel, gap_rel, tol = scale_tolerance(ball, plates)
    scale = Scale(ball_diameter_mm / (2 * ball.radius_px), gap_mm / plates.gap_px, ball_rel, gap_rel, tol)
    if abs(scale.disagreement_rel) > tol:
        raise InitError(
            f"scale from the ball ({ball_diameter_mm:g} mm over {2 * ball.radius_px:.2f} +- "
            f"{2 * ball.radius_std_px:.2f} px = {scale.from_ball:.5f} mm/px) and from the gap ({gap_mm:g} mm over "
            f"{plates.gap_px:.2f} +- {plates.gap_std_px:.2f} px = {scale.from_gap:.5f} mm/px) disagree by "
            f"{100 * scale.disagreement_rel:+.2f} % (localisation allows {100 * tol:.2f} %): check --ball-diameter-mm "
            "and --gap-mm")
    ball_roi = outline_roi if outline_roi is not None else propose_ball_roi(ball, subset_px, w, h)
    structure_roi, which = propose_structure_roi(plates, motion, subset_px, mesh_step_px, w, h)
    cavity = np.zeros(frame0.shape, bool)
    cavity[int(plates.top_row_px) + 4:int(plates.bottom_row_px) - 3] = True
    yy, xx = np.mgrid[:h, :w]
    cavity &= np.hypot(xx - ball.x_px, yy - ball.y_px) > ball.radius_px + 4
    cavity &= ~clipped_gray255(frame0, effective_bits)
    noise = noise_sigma_gray(frame0, cavity if cavity.sum() > 500 else None, effective_bits=effective_bits)
    checked = [("structure", worst_cramer_rao_px(frame0, structure_roi, subset_px, mesh_step_px, noise))]
    check = None
    if outline_roi is not None:
        # a plain ball: no subsets inside it; its outline's accuracy is predicted instead (the texture check's)
        check = outline.assess_outline("ball", np.asarray(frame0, np.float32), outline_roi, noise)
        if check.refused:
            raise InitError(f"found {ball.describe()}, but {check.problem()}")
        cr_ball = math.nan
    else:
        cr_ball = worst_cramer_rao_px(frame0, ball_roi, subset_px, mesh_step_px, noise)
        checked.insert(0, ("ball", cr_ball))
    cr_struct = checked[-1][1]
    for name, cr in checked:
        if not cr <= MAX_SUBSET_CRAMER_RAO_PX:  # NaN (no measurement) fails too
            raise InitError(f"the {name} ROI has too little texture for DIC: its worst {subset_px} px subset's "
                            f"displacement std would be {cr:.3f} px (sum of squared gradients against the noise, "
                            f"{noise:.2f} gray levels; need <= {MAX_SUBSET_CRAMER_RAO_PX} px): speckle the {name}, "
                            "light it better or give a larger --subset-px")
    freq, note = estimate_frequency_hz(motion, fps)
    return Proposal(width_px=w, height_px=h, ball=ball, plates=plates, motion=motion, scale=scale, ball_roi=ball_roi,
                    structure_roi=structure_roi, structure_plate=which, subset_px=subset_px, mesh_step_px=mesh_step_px,
                    noise_gray=noise, edge_sigma_px=edge_sigma, ball_cramer_rao_px=cr_ball,
                    structure_cramer_rao_px=cr_struct, frequency_hz=freq, frequency_note=note, ball_outline=check)
