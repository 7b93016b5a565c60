"""The whole-image search coarse to fine (vibro_dic.search.whole_image_search): the position the full search finds,
from the half-resolution level when the pattern allows it, and from the full search when it does not."""

from __future__ import annotations

import numpy as np
import pytest

from vibro_dic import search
from vibro_dic.search import half_resolution, whole_image_search, zncc_search
from vibro_dic.speckle import speckle_pattern

ZNCC_MIN = 0.6


def _full(image: np.ndarray, template: np.ndarray) -> search.SearchResult:
    rows, cols = image.shape
    return zncc_search(image, template, 0, cols, 0, rows)


def _count_full_searches(monkeypatch, image: np.ndarray) -> list[int]:
    """Counts the calls of zncc_search that cover the whole of ``image``."""
    calls = []
    real = search.zncc_search

    def counting(img, template, x_lo, x_hi, y_lo, y_hi):
        if img is image and x_lo <= 0 and y_lo <= 0 and x_hi >= img.shape[1] - template.shape[1] \
                and y_hi >= img.shape[0] - template.shape[0]:
            calls.append(1)
        return real(img, template, x_lo, x_hi, y_lo, y_hi)

    monkeypatch.setattr(search, "zncc_search", counting)
    return calls


@pytest.mark.parametrize("size", [(41, 41), (41, 141), (24, 30)])
def test_speckle_is_found_where_the_full_search_finds_it_without_searching_all_of_it(monkeypatch, size) -> None:
    rng = np.random.default_rng(5)
    image = speckle_pattern((480, 160), seed=11).render().astype(np.float32)
    image += rng.normal(0.0, 2.0, image.shape).astype(np.float32)  # camera noise: the template is not exact
    th, tw = size
    full_calls = _count_full_searches(monkeypatch, image)
    for _ in range(12):
        x, y = int(rng.integers(0, 160 - tw + 1)), int(rng.integers(0, 480 - th + 1))
        template = speckle_pattern((480, 160), seed=11).render().astype(np.float32)[y:y + th, x:x + tw]
        got = whole_image_search(image, template, half_resolution(template), ZNCC_MIN)
        want = _full(image, template)
        assert (got.x, got.y) == (want.x, want.y) == (x, y)
        assert got.zncc == pytest.approx(want.zncc, abs=1e-5)
        assert got.sub_dx == pytest.approx(want.sub_dx, abs=1e-3) and got.sub_dy == pytest.approx(want.sub_dy, abs=1e-3)
    assert not full_calls  # every one answered at half resolution and in the small window


def _fine_only_pattern(shape: tuple[int, int], seed: int) -> np.ndarray:
    """Random texture with no spatial frequency under 0.3 cycles/px: half resolution (pyrDown's Gaussian passes
    under 12 % there, and every 2nd pixel aliases the rest) keeps nothing the full image's positions share."""
    rng = np.random.default_rng(seed)
    spec = np.fft.rfft2(rng.standard_normal(shape))
    f = np.hypot(np.fft.fftfreq(shape[0])[:, None], np.fft.rfftfreq(shape[1])[None, :])
    spec[f < 0.3] = 0.0
    img = np.fft.irfft2(spec, s=shape)
    return (128.0 + 40.0 * img / img.std()).astype(np.float32)


def test_a_pattern_half_resolution_cannot_see_falls_back_to_the_full_search(monkeypatch) -> None:
    image = _fine_only_pattern((200, 120), seed=2)
    x, y = 37, 91  # odd: the template's half-resolution grid is not the image's
    template = image[y:y + 32, x:x + 32].copy()
    half = half_resolution(image)
    coarse = zncc_search(half, half_resolution(template), 0, half.shape[1], 0, half.shape[0])
    assert max(abs(2 * coarse.x - x), abs(2 * coarse.y - y)) > search.COARSE_WINDOW_PX  # the coarse level misses
    full_calls = _count_full_searches(monkeypatch, image)
    got = whole_image_search(image, template, half_resolution(template), ZNCC_MIN)
    assert (got.x, got.y) == (x, y) and got.zncc == pytest.approx(1.0, abs=1e-4)
    assert full_calls == [1]


def test_a_small_template_or_none_at_half_resolution_searches_the_full_image(monkeypatch) -> None:
    image = speckle_pattern((120, 90), seed=4).render().astype(np.float32)
    full_calls = _count_full_searches(monkeypatch, image)
    small = image[30:42, 20:32].copy()  # 12 px: under MIN_COARSE_TEMPLATE_PX
    assert min(small.shape) < search.MIN_COARSE_TEMPLATE_PX
    got = whole_image_search(image, small, half_resolution(small), ZNCC_MIN)
    assert (got.x, got.y) == (20, 30)
    big = image[10:50, 40:80].copy()
    got = whole_image_search(image, big, None, ZNCC_MIN)
    assert (got.x, got.y) == (40, 10)
    assert full_calls == [1, 1]
