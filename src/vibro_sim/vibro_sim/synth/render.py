"""Render the synthetic camera frames with true sub-pixel motion.

Geometry (pixel centres at integer indices, rows grow downwards): the lab height z
(mm, positive up, 0 = the structure's mean position) maps to the row
``row_mid - z / mm_per_px`` with ``row_mid = (height - 1) / 2``; the ball's centre is on
column ``(width - 1) / 2``.

Sub-pixel motion is exact for band-limited content: the speckle textures are
Gaussian-blurred random impulses (sigma 1.3 px, so the spectrum at Nyquist is ~1e-3)
and every moving layer is shifted by a Fourier phase ramp along the rows (the
structure layer as a whole; the ball as a small patch shifted by its fractional row
then pasted at the integer row). Layers carry an alpha channel (smooth erf edges) and
are composited over a static background. Then a mild global illumination flicker and
Gaussian read noise are applied and the result is quantised.

A spinning ball (``Renderer(..., spin=True)``) keeps the same speckle impulses but draws its
patch analytically every frame: each impulse is a Gaussian blob (the same sigma) at its position
rotated about the ball centre by the frame's angle (+ counter-clockwise as the camera sees the
image) and moved by the fractional row; the disc's erf edge and shading are evaluated about the
same sub-pixel centre. Without spin the frames are exactly those drawn before spin existed.

An unspeckled, shiny ball (``Renderer(..., ball_surface="shiny")``, real footage's common case) is a dark
glossy sphere drawn analytically every frame about its sub-pixel centre (orthographic camera): ambient +
Lambert diffuse + Blinn-Phong specular of one directional light at ``light_deg`` from the camera axis,
tilted towards the top of the image. Its highlight sits where the sphere's normal bisects the light and
view directions, ``R sin(light_deg / 2)`` above the centre: fixed relative to the light, so it moves with
the ball's centre but never with a texture (a spinning shiny ball looks the same). The highlight's core
saturates (clipped at 255), as it does on film.

A plain ball (``Renderer(..., ball_surface="plain")``: no speckle, backlit, the way drop and bounce tests are
filmed) is a uniformly dark disc (:data:`PLAIN_BALL_GRAY`) in front of a bright backlight
(:data:`PLAIN_BACKLIGHT_GRAY`; its blotches defocused to :data:`PLAIN_BACKLIGHT_BLUR_PX`, as a backlight far
behind the focal plane is), drawn analytically every frame about its sub-pixel centre. Its outline is sharp and
anti-aliased: an erf edge of :data:`PLAIN_EDGE_SIGMA_PX` (a 0.5 px lens blur and the pixel's area,
sqrt(0.5^2 + 1/12) px), symmetric about the true radius, so the outline's 50 % level lies on the true circle.
Only DIC's structure ROI needs texture: the plates keep their speckle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.fft import next_fast_len
from scipy.ndimage import gaussian_filter
from scipy.special import erf

SPECKLE_SIGMA_PX = 1.3
EDGE_SIGMA_PX = 1.5  # erf edges: spectrum at Nyquist exp(-(pi 1.5)^2 / 2) ~ 1e-5, no ringing


@dataclass(frozen=True)
class Layout:
    """Image geometry: size, scale and where the physics lands in pixels."""

    width_px: int
    height_px: int
    mm_per_px: float
    ball_radius_px: float
    gap_px: float
    margin_px: int  # padding of the moving structure canvas (> max shift)

    @property
    def row_mid(self) -> float:
        return 0.5 * (self.height_px - 1)

    @property
    def col_mid(self) -> float:
        return 0.5 * (self.width_px - 1)

    def row_of_mm(self, z_mm):
        """Image row of lab height z (mm) with no camera drift."""
        return self.row_mid - np.asarray(z_mm, dtype=float) / self.mm_per_px


OUTLINE_ROI_MARGIN_PX = 6  # a plain ball's ROI reaches this far beyond its outline
ROI_MARGIN_PX = 6      # structure ROI starts this far inside the plate (> 3 edge sigmas)
STRUCT_ROI_H_PX = 45   # structure ROI height
DEFAULT_MM_PER_PX = 0.06


def choose_layout(width_px: int, height_px: int, ball_diameter_mm: float, gap_mm: float,
                  amplitude_mm: float, mm_per_px: float | None, subset_px: int,
                  drift_px: float = 0.0) -> Layout:
    """Pick the scale: 0.06 mm/px unless the lower plate's ROI would leave the image.

    The structure ROI sits on the lower plate in frame 0 and must stay in the image for
    every frame: (gap/2 + A)/s + margin + ROI height <= row_mid (independent of the phase
    at frame 0), so s >= (gap/2 + A) / (row_mid - margin - ROI height).
    """
    row_mid = 0.5 * (height_px - 1)
    room = row_mid - ROI_MARGIN_PX - STRUCT_ROI_H_PX - abs(drift_px) - 2
    need = (0.5 * gap_mm + amplitude_mm) / room if room > 0 else math.inf
    scale = mm_per_px if mm_per_px is not None else max(DEFAULT_MM_PER_PX, need)
    if scale < need:
        raise ValueError(f"mm_per_px {scale} is too fine: the plates' travel needs >= {need:.4f} mm/px "
                         f"for a {height_px} px high image")
    radius_px = 0.5 * ball_diameter_mm / scale
    if (radius_px - 3 * EDGE_SIGMA_PX - 1.0) * math.sqrt(2) < subset_px:
        why = (f" (the plates' travel of +-{amplitude_mm:.2f} mm needs >= {need:.4f} mm/px in a "
               f"{height_px} px high image)" if scale == need else "")
        raise ValueError(f"the ball ({2 * radius_px:.1f} px across at {scale:.4f} mm/px{why}) cannot hold "
                         f"a {subset_px} px subset; lower the shaker amplitude or use a larger image")
    if 2 * radius_px + 8 > width_px:
        raise ValueError(f"the ball ({2 * radius_px:.1f} px) does not fit the {width_px} px wide image")
    margin = int(math.ceil(amplitude_mm / scale * 3.5 + abs(drift_px) + 24))
    return Layout(width_px, height_px, scale, radius_px, gap_mm / scale, margin)


def _impulses(rng: np.random.Generator, shape: tuple[int, int], density: float) -> np.ndarray:
    """Random impulses of amplitude U(0.5, 1) on a fraction ``density`` of the pixels."""
    return (rng.random(shape) < density) * rng.uniform(0.5, 1.0, shape)


def _speckle_of(imp: np.ndarray, sigma_px: float) -> tuple[np.ndarray, float]:
    """(speckle field in about [0, 1], the scale it was divided by) of impulses ``imp``."""
    field = gaussian_filter(imp.astype(np.float64), sigma_px, mode="wrap")
    scale = max(float(np.quantile(field, 0.995)), 1e-12)
    return field / scale, scale


def speckle(rng: np.random.Generator, shape: tuple[int, int], density: float = 0.05,
            sigma_px: float = SPECKLE_SIGMA_PX) -> np.ndarray:
    """Band-limited speckle in about [0, 1]: blurred random impulses."""
    return _speckle_of(_impulses(rng, shape, density), sigma_px)[0]


class _SpinningBall:
    """The ball patch drawn analytically: speckle blobs rotated about the ball centre (see module doc)."""

    def __init__(self, imp: np.ndarray, scale: float, radius_px: float, centre_row: float, centre_col: float):
        rows, cols = np.nonzero(imp)
        # only blobs that can reach the disc at some angle (5 sigma beyond the edge) are drawn
        near = np.hypot(rows - centre_row, cols - centre_col) <= radius_px + 3 * EDGE_SIGMA_PX + 5 * SPECKLE_SIGMA_PX
        rows, cols = rows[near], cols[near]
        self.amp = imp[rows, cols] / scale
        self.y0 = rows - centre_row  # blob positions relative to the ball centre (px, rows down)
        self.x0 = cols - centre_col
        n = imp.shape[0]
        self.pr = np.arange(n) - centre_row
        self.pc = np.arange(imp.shape[1]) - centre_col
        self.radius_px = radius_px
        self.norm = 1.0 / (math.sqrt(2.0 * math.pi) * SPECKLE_SIGMA_PX)

    def _g(self, d: np.ndarray) -> np.ndarray:
        return self.norm * np.exp(-0.5 * (d / SPECKLE_SIGMA_PX) ** 2)

    def patch(self, down_px: float, angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
        """(premultiplied value, alpha) of the patch with the ball moved down by ``down_px`` (fractional)
        and its texture turned by ``angle_rad`` (+ counter-clockwise on screen: x' = x cos + y sin,
        y' = -x sin + y cos with y down)."""
        c, s = math.cos(angle_rad), math.sin(angle_rad)
        xb = self.x0 * c + self.y0 * s
        yb = -self.x0 * s + self.y0 * c + down_px
        gy = self._g(self.pr[:, None] - yb[None, :])          # (rows, blobs)
        gx = self._g(self.pc[:, None] - xb[None, :])          # (cols, blobs)
        # einsum, not BLAS: a multi-threaded BLAS on this small product is 40x slower under load
        tex = np.einsum("rb,cb->rc", gy * self.amp[None, :], gx)
        r = np.sqrt((self.pr[:, None] - down_px) ** 2 + self.pc[None, :] ** 2)
        alpha = _smooth_step(self.radius_px - r)
        shade = 1.0 - 0.25 * np.clip(r / self.radius_px, 0, 1) ** 2
        return (60.0 + 180.0 * tex) * shade * alpha, alpha


SHINY_AMBIENT = 12.0   # gray levels of the dark sphere without light
SHINY_DIFFUSE = 18.0   # Lambert term at normal incidence
SHINY_SPECULAR = 260.0  # Blinn-Phong peak (the core clips at 255)
SHINY_GLOSS = 150.0    # Blinn-Phong exponent: the highlight's normal-angle std is 1/sqrt(150) = 4.7 deg


class _ShinyBall:
    """A dark glossy sphere without texture, lit by a directional light (see module doc)."""

    def __init__(self, patch_px: int, radius_px: float, centre_row: float, centre_col: float, light_deg: float):
        self.pr = np.arange(patch_px) - centre_row
        self.pc = np.arange(patch_px) - centre_col
        self.radius_px = radius_px
        th = math.radians(light_deg)
        # camera axes: x right, y down (rows), z towards the camera; the light is tilted towards the image top
        self.light = np.array([0.0, -math.sin(th), math.cos(th)])
        half = self.light + np.array([0.0, 0.0, 1.0])
        self.half = half / np.linalg.norm(half)

    def patch(self, down_px: float, angle_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(premultiplied value, alpha) with the ball moved down by ``down_px`` (fractional); ``angle_rad``
        is ignored: an untextured sphere looks the same at any spin."""
        y = self.pr[:, None] - down_px
        x = self.pc[None, :]
        r = np.sqrt(x ** 2 + y ** 2)
        alpha = _smooth_step(self.radius_px - r)
        rr = np.maximum(r, 1e-12)
        scale = np.minimum(rr, self.radius_px) / rr  # outside the disc: the limb's normal (under the erf edge)
        nx, ny = x * scale / self.radius_px, y * scale / self.radius_px
        nz = np.sqrt(np.clip(1.0 - nx ** 2 - ny ** 2, 0.0, 1.0))
        lam = np.clip(nx * self.light[0] + ny * self.light[1] + nz * self.light[2], 0.0, None)
        spec = np.clip(nx * self.half[0] + ny * self.half[1] + nz * self.half[2], 0.0, None) ** SHINY_GLOSS
        value = SHINY_AMBIENT + SHINY_DIFFUSE * lam + SHINY_SPECULAR * spec * (lam > 0)
        return value * alpha, alpha


PLAIN_BALL_GRAY = 30.0         # the backlit ball's silhouette (gray levels of 255)
PLAIN_BACKLIGHT_GRAY = 200.0   # the backlight behind it (+ a 20 gray-level vertical gradient, faint blotches)
#: the backlight is far behind the focal plane: its nonuniformity (the same 4 gray-level blotches) is defocused to
#: this sigma (px). Sharper blotches under the outline bias its edges: 6 px ones give 0.0015 px (std over positions)
PLAIN_BACKLIGHT_BLUR_PX = 24.0
PLAIN_EDGE_SIGMA_PX = math.sqrt(0.5 ** 2 + 1.0 / 12.0)  # lens blur 0.5 px and the pixel's area: 0.58 px


class _PlainBall:
    """A uniformly dark disc with a sharp anti-aliased outline (see module doc)."""

    def __init__(self, patch_px: int, radius_px: float, centre_row: float, centre_col: float):
        self.pr = np.arange(patch_px) - centre_row
        self.pc = np.arange(patch_px) - centre_col
        self.radius_px = radius_px

    def patch(self, down_px: float, angle_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(premultiplied value, alpha) with the ball moved down by ``down_px`` (fractional); ``angle_rad`` is
        ignored: a plain disc looks the same at any spin."""
        r = np.sqrt((self.pr[:, None] - down_px) ** 2 + self.pc[None, :] ** 2)
        alpha = 0.5 * (1.0 + erf((self.radius_px - r) / (math.sqrt(2.0) * PLAIN_EDGE_SIGMA_PX)))
        return PLAIN_BALL_GRAY * alpha, alpha


BALL_SURFACES = ("speckle", "shiny", "plain")


def _smooth_step(x):
    """0 -> 1 across x = 0 with an erf edge of width EDGE_SIGMA_PX (x in px)."""
    return 0.5 * (1.0 + erf(x / (math.sqrt(2.0) * EDGE_SIGMA_PX)))


class _ShiftLayer:
    """A (value, alpha) layer shifted along rows by a Fourier phase ramp.

    Two real columns share one complex FFT (the second as the imaginary part; the inverse of a Hermitian
    spectrum is real, so the two come back apart exactly). A layer whose alpha is the same in every column (the
    structure's plates, the background) keeps one alpha column and pairs its value columns: half the transforms
    of value + 1j alpha per column, the same pixels to float round-off. Spectra are stored one column pair per
    row (the transform along the last, contiguous axis).
    """

    def __init__(self, premult: np.ndarray, alpha: np.ndarray):
        self.n, self.width = premult.shape
        self.row_alpha = bool(np.all(alpha == alpha[:, :1]))
        if self.row_alpha:
            value = premult if self.width % 2 == 0 else np.pad(premult, ((0, 0), (0, 1)))
            packed = np.concatenate([value[:, 0::2] + 1j * value[:, 1::2], alpha[:, :1] + 0j], axis=1)
        else:
            packed = premult + 1j * alpha
        # transformed over a length with small prime factors (a canvas of 698 rows = 2 x 349 took 0.72 ms per
        # inverse, 700 rows 0.2 ms): the rows added are empty and lie beyond the margin no shift brings into view
        n_fft = next_fast_len(self.n)
        packed = np.pad(packed, ((0, n_fft - self.n), (0, 0)))
        self.spec = np.ascontiguousarray(np.fft.fft(packed, axis=0).T)
        if n_fft % 2 == 0:
            # A fractional shift of the Nyquist row is not real: it would leak one column into its pair
            # (they share one complex FFT). Band-limited layers hold ~nothing there.
            self.spec[:, n_fft // 2] = 0.0
        self.k = np.fft.fftfreq(n_fft)

    def _inverse(self, ramp: np.ndarray | None, start: int, stop: int | None) -> tuple[np.ndarray, np.ndarray]:
        """(value, alpha) rows ``start:stop`` of the inverse FFT of the spectrum times ``ramp`` (None: 1); alpha
        is one column (broadcasts) for a layer whose alpha is the same in every column."""
        out = np.fft.ifft(self.spec if ramp is None else self.spec * ramp, axis=-1)[:, :self.n][:, start:stop]
        if not self.row_alpha:
            return out.real.T, out.imag.T
        pairs = out[:-1]
        value = np.empty((out.shape[1], 2 * pairs.shape[0]))
        value[:, 0::2] = pairs.real.T
        value[:, 1::2] = pairs.imag.T
        return value[:, :self.width], out[-1].real[:, None]

    def shifted_mean(self, rows: np.ndarray, start: int = 0,
                     stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Mean of the layer over several shifts (exact: one averaged phase ramp), rows ``start:stop``."""
        ramp = np.mean(np.exp(-2j * math.pi * self.k[None, :] * np.asarray(rows, float)[:, None]), axis=0)
        return self._inverse(ramp, start, stop)

    def shifted(self, rows: float, start: int = 0, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Content moved down by ``rows`` (may be fractional), rows ``start:stop`` of it."""
        return self._inverse(None if rows == 0.0 else np.exp(-2j * math.pi * self.k * rows), start, stop)


class Renderer:
    """Draws one frame from the structure displacement and the ball height (mm)."""

    def __init__(self, layout: Layout, rng: np.random.Generator, drift: bool = False, spin: bool = False,
                 ball_surface: str = "speckle", light_deg: float = 30.0):
        self.L = layout
        H, W, M = layout.height_px, layout.width_px, layout.margin_px
        rows = np.arange(H)[:, None]
        cols = np.arange(W)[None, :]
        # static background: dim gradient with faint blurred blotches (a bright backlight behind a plain ball)
        bg = 55.0 + 20.0 * rows / H + 6.0 * np.sin(cols / W * math.pi)
        blot = cv2.GaussianBlur(rng.random((H + 2 * M, W)), (0, 0), 6.0)
        blot = (blot - blot.mean()) / (blot.std() + 1e-12)
        if ball_surface == "plain":  # a backlight, far behind the focal plane: its blotches defocused
            bg = bg + (PLAIN_BACKLIGHT_GRAY - 55.0)
            blot = cv2.GaussianBlur(blot, (0, 0), PLAIN_BACKLIGHT_BLUR_PX)
            blot = (blot - blot.mean()) / (blot.std() + 1e-12)
        self.drift = drift
        if drift:  # the background moves with the camera too: keep it as a padded layer
            bgc = np.pad(bg, ((M, M), (0, 0)), mode="edge") + 4.0 * blot
            self.bg_layer = _ShiftLayer(bgc, np.ones_like(bgc))
            self.background = None
        else:
            self.background = bg + 4.0 * blot[M:M + H]
        # structure canvas: plates above and below the cavity, speckled
        Hc = H + 2 * M
        q = np.arange(Hc)[:, None] - (layout.row_mid + M)
        dist = np.abs(q) - 0.5 * layout.gap_px  # > 0 inside a plate
        alpha_s = np.broadcast_to(_smooth_step(dist), (Hc, W)).copy()
        tex = 45.0 + 175.0 * speckle(rng, (Hc, W))
        tex *= 1.0 - 0.08 * np.exp(-np.maximum(dist, 0) / 12.0)  # slight shading near the edges
        self.struct_layer = _ShiftLayer(tex * alpha_s, alpha_s)
        # ball patch: speckled disc with mild spherical shading
        R = layout.ball_radius_px
        hp = int(2 * math.ceil(R + 8))
        self.patch_rows = hp
        self.patch_centre_row = hp // 2
        self.patch_col0 = int(round(layout.col_mid - (hp / 2 - 0.5)))
        pr = np.arange(hp)[:, None] - self.patch_centre_row
        pc = np.arange(hp)[None, :] - (hp / 2 - 0.5)
        r = np.sqrt(pr ** 2 + pc ** 2)
        alpha_b = _smooth_step(R - r)
        shade = 1.0 - 0.25 * np.clip(r / R, 0, 1) ** 2
        imp_b = _impulses(rng, (hp, hp), 0.06)
        field_b, scale_b = _speckle_of(imp_b, SPECKLE_SIGMA_PX)
        tex_b = (60.0 + 180.0 * field_b) * shade
        self.ball_layer = _ShiftLayer(tex_b * alpha_b, alpha_b)
        self.spinning_ball = (_SpinningBall(imp_b, scale_b, R, self.patch_centre_row, hp / 2 - 0.5)
                              if spin else None)
        if ball_surface not in BALL_SURFACES:
            raise ValueError(f"ball surface must be one of {BALL_SURFACES}, got {ball_surface!r}")
        # the speckle draws above stay, so that the rest of the scene is the same whatever the ball's surface
        self.shiny_ball = (_ShinyBall(hp, R, self.patch_centre_row, hp / 2 - 0.5, light_deg)
                           if ball_surface == "shiny" else None)
        self.plain_ball = (_PlainBall(hp, R, self.patch_centre_row, hp / 2 - 0.5)
                           if ball_surface == "plain" else None)

    def _ball_over(self, img: np.ndarray, ball_mm: float, dr: float, angle_rad: float = 0.0) -> np.ndarray:
        L = self.L
        H, W = L.height_px, L.width_px
        row_b = float(L.row_of_mm(ball_mm)) + dr
        ri = math.floor(row_b)
        if self.plain_ball is not None:
            pv, pa = self.plain_ball.patch(row_b - ri, angle_rad)
        elif self.shiny_ball is not None:
            pv, pa = self.shiny_ball.patch(row_b - ri, angle_rad)
        elif self.spinning_ball is not None:
            pv, pa = self.spinning_ball.patch(row_b - ri, angle_rad)
        else:
            pv, pa = self.ball_layer.shifted(row_b - ri)
        top = ri - self.patch_centre_row
        r0, r1 = max(top, 0), min(top + self.patch_rows, H)
        if r1 > r0:
            c0 = self.patch_col0
            c1 = c0 + self.patch_rows
            cs0, cs1 = max(c0, 0), min(c1, W)
            sub_v = pv[r0 - top:r1 - top, cs0 - c0:cs1 - c0]
            sub_a = pa[r0 - top:r1 - top, cs0 - c0:cs1 - c0]
            img[r0:r1, cs0:cs1] = img[r0:r1, cs0:cs1] * (1.0 - sub_a) + sub_v
        return img

    def render_blurred(self, structure_mm, ball_mm, drift_mm: float = 0.0, ball_angle_rad=None) -> np.ndarray:
        """Mean image over an exposure sampled at positions ``structure_mm[j]``, ``ball_mm[j]`` (and the
        ball's texture angles ``ball_angle_rad[j]`` when it spins).

        Exact per layer (the structure layer uses one averaged phase ramp); compositing
        uses the mean ball image under the mean structure alpha, which differs from the
        mean of the composites only where the ball and a plate edge overlap during the
        exposure (at contact, outside the ROIs).
        """
        L = self.L
        H, M = L.height_px, L.margin_px
        dr = -drift_mm / L.mm_per_px
        base = self.background if not self.drift else self.bg_layer.shifted(dr, M, M + H)[0]
        angles = np.zeros(len(ball_mm)) if ball_angle_rad is None else np.asarray(ball_angle_rad, dtype=float)
        under = np.mean([self._ball_over(base.copy(), b, dr, a) for b, a in zip(ball_mm, angles)], axis=0)
        sv, sa = self.struct_layer.shifted_mean(-np.asarray(structure_mm, float) / L.mm_per_px + dr, M, M + H)
        return under * (1.0 - sa) + sv

    def render(self, structure_mm: float, ball_mm: float, drift_mm: float = 0.0,
               ball_angle_rad: float = 0.0) -> np.ndarray:
        """Float image (gray levels of 255) for structure displacement and ball height (mm).

        ``drift_mm``: apparent upward shift of the whole scene (camera drift); ``ball_angle_rad``: the
        ball texture's rotation (+ counter-clockwise on screen; a renderer built with ``spin=True``).
        """
        L = self.L
        H, M = L.height_px, L.margin_px
        dr = -drift_mm / L.mm_per_px  # rows down
        if self.drift:
            img = self.bg_layer.shifted(dr, M, M + H)[0]
        else:
            img = self.background.copy()
        img = self._ball_over(img, ball_mm, dr, ball_angle_rad)
        # structure on top
        sv, sa = self.struct_layer.shifted(-structure_mm / L.mm_per_px + dr, M, M + H)
        return img * (1.0 - sa) + sv

    def ball_roi(self, ball_mm0: float, subset_px: int) -> list[int]:
        """[x, y, w, h] square well inside the ball disc in frame 0."""
        L = self.L
        # corners at least 3 edge sigmas + 1 px inside the disc edge: alpha > 0.9998 there
        side = int(math.floor((L.ball_radius_px - 3 * EDGE_SIGMA_PX - 1.0) * math.sqrt(2.0)))
        side = max(side, subset_px)
        rc = float(L.row_of_mm(ball_mm0))
        x = int(round(L.col_mid - side / 2 + 0.5))
        y = int(round(rc - side / 2 + 0.5))
        return [x, y, side, side]

    def outline_roi(self, ball_mm0: float, margin_px: int = OUTLINE_ROI_MARGIN_PX) -> list[int]:
        """[x, y, w, h] box around the whole ball in frame 0 with ``margin_px`` beyond its outline (px), kept
        inside the image: what a plain ball's outline tracking (rig.yaml ``dic.ball_method: outline``) needs."""
        L = self.L
        half = L.ball_radius_px + margin_px
        rc = float(L.row_of_mm(ball_mm0))
        x0 = max(int(math.floor(L.col_mid - half)), 0)
        y0 = max(int(math.floor(rc - half)), 0)
        x1 = min(int(math.ceil(L.col_mid + half)) + 1, L.width_px)
        y1 = min(int(math.ceil(rc + half)) + 1, L.height_px)
        return [x0, y0, x1 - x0, y1 - y0]

    def structure_roi(self, structure_mm0: float) -> list[int]:
        """[x, y, w, h] on the lower plate in frame 0, starting ROI_MARGIN_PX below its edge."""
        L = self.L
        edge = float(L.row_of_mm(structure_mm0)) + 0.5 * L.gap_px
        y = int(math.ceil(edge + ROI_MARGIN_PX))
        x = 8
        return [x, y, L.width_px - 16, STRUCT_ROI_H_PX]


def quantise(img: np.ndarray, tiff16: bool, jpeg_quality: int = 0, bits12: bool = False) -> np.ndarray:
    """Round a float image (gray levels of 255) to uint8, or to uint16 (x 257). ``jpeg_quality`` 1..100: the
    8-bit image then goes through a JPEG encode/decode at that quality (lossy video; 0 = none). ``bits12``: a
    12-bit camera's codes (x 4095 / 255, rounded) at the top of uint16 words (x 16), as Photron files hold them."""
    if bits12:
        return (np.clip(np.rint(img * (4095.0 / 255.0)), 0, 4095).astype(np.uint16) << 4).astype(np.uint16)
    if tiff16:
        return np.clip(np.rint(img * 257.0), 0, 65535).astype(np.uint16)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if jpeg_quality:
        ok, enc = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise ValueError("JPEG encoding failed")
        out = cv2.imdecode(enc, cv2.IMREAD_GRAYSCALE)
    return out
