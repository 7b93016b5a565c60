"""Integer ZNCC search (paper Eq. 1) and parabolic sub-pixel peak fit.

ZNCC(u) = sum (f - f_mean)(g(x + u) - g_mean) / (||f - f_mean|| ||g - g_mean||), which is
OpenCV's TM_CCOEFF_NORMED. Pixel convention: x = column, y = row.

:func:`whole_image_search` finds a template anywhere in the image coarse to fine: the whole image at half
resolution (``cv2.pyrDown``, 1/16 of the work), then full resolution in a small window around that peak; the full
search only when that window's peak is not a clear one.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class SearchResult:
    """Best integer top-left (x, y) of the template in the image, its ZNCC, a parabolic
    sub-pixel offset (dx, dy) in [-0.5, 0.5], and whether the peak sits on the window's border."""

    x: int
    y: int
    zncc: float
    sub_dx: float
    sub_dy: float
    on_border: bool


def parabolic_offset(c_minus: float, c_0: float, c_plus: float) -> float:
    """Vertex of the parabola through (-1, c_minus), (0, c_0), (1, c_plus), clipped to [-0.5, 0.5] px."""
    den = c_minus - 2.0 * c_0 + c_plus
    if not np.isfinite(den) or den >= 0.0:
        return 0.0
    return float(np.clip(0.5 * (c_minus - c_plus) / den, -0.5, 0.5))


def zncc_search(image: np.ndarray, template: np.ndarray, x_lo: int, x_hi: int, y_lo: int, y_hi: int
                ) -> SearchResult | None:
    """Search top-left positions x in [x_lo, x_hi], y in [y_lo, y_hi] (clipped to the image).

    ``image`` and ``template`` must share a dtype (uint8 or float32). Returns None when
    no position inside the image is left.
    """
    th, tw = template.shape
    rows, cols = image.shape
    x_lo, y_lo = max(x_lo, 0), max(y_lo, 0)
    x_hi, y_hi = min(x_hi, cols - tw), min(y_hi, rows - th)
    if x_hi < x_lo or y_hi < y_lo:
        return None
    window = image[y_lo: y_hi + th, x_lo: x_hi + tw]
    corr = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    _, peak, _, (px, py) = cv2.minMaxLoc(corr)
    h, w = corr.shape
    if not np.isfinite(peak):
        return None
    sub_dx = parabolic_offset(corr[py, px - 1], peak, corr[py, px + 1]) if 0 < px < w - 1 else 0.0
    sub_dy = parabolic_offset(corr[py - 1, px], peak, corr[py + 1, px]) if 0 < py < h - 1 else 0.0
    on_border = (px == 0 and x_lo > 0) or (px == w - 1 and x_hi < cols - tw) or \
                (py == 0 and y_lo > 0) or (py == h - 1 and y_hi < rows - th)
    return SearchResult(x_lo + px, y_lo + py, float(peak), sub_dx, sub_dy, bool(on_border))


#: (px, full resolution) half-width of the window searched around the half-resolution peak: the peak of a template
#: at top-left x in the full image is at x/2 +- 0.5 at half resolution, so +-1 px would do; 3 leaves margin
COARSE_WINDOW_PX = 3
#: (px) smallest template side searched at half resolution: smaller ones keep too few speckles there
MIN_COARSE_TEMPLATE_PX = 16


def half_resolution(image: np.ndarray) -> np.ndarray:
    """The image at half resolution (Gaussian 5x5 then every 2nd row and column, ``cv2.pyrDown``)."""
    return cv2.pyrDown(image)


def whole_image_search(image: np.ndarray, template: np.ndarray, half_template: np.ndarray | None,
                       zncc_min: float) -> SearchResult | None:
    """The template's best position in the whole image (:func:`zncc_search` over every position), coarse to fine:
    the whole image searched at half resolution with ``half_template`` (:func:`half_resolution` of ``template``;
    None: no coarse level), then the full image in +-:data:`COARSE_WINDOW_PX` around that peak. That window's peak
    is returned when it is a clear one (ZNCC >= ``zncc_min``, not on the window's border); else (a pattern too fine
    for half resolution) the whole image at full resolution, as without the coarse level."""
    th, tw = template.shape
    if half_template is not None and min(th, tw) >= MIN_COARSE_TEMPLATE_PX:
        half = half_resolution(image)
        coarse = zncc_search(half, half_template, 0, half.shape[1], 0, half.shape[0])
        if coarse is not None and coarse.zncc >= zncc_min:
            r = COARSE_WINDOW_PX
            x, y = 2 * coarse.x, 2 * coarse.y
            fine = zncc_search(image, template, x - r, x + r, y - r, y + r)
            if fine is not None and not fine.on_border and fine.zncc >= zncc_min:
                return fine
    rows, cols = image.shape
    return zncc_search(image, template, 0, cols, 0, rows)
