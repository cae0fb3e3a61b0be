"""The second look's index, CIELAB −a*/100 (`capm_field.vegetation.neg_a_star`), against CIE's
definition: published sRGB → L*a*b* values, and a plain float64 transcription of the formulas."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from capm_field import vegetation as veg
from capm_field.vegetation import _scaled, greenness, neg_a_star, vegetation_index


def _a_star_reference(rgb: np.ndarray) -> np.ndarray:
    """a* of sRGB values on 0–1 (D65), term by term as IEC 61966-2-1 and CIE 15 write them."""
    c = np.clip(np.asarray(rgb, np.float64), 0.0, 1.0)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    r, g, b = lin[..., 0], lin[..., 1], lin[..., 2]
    x = (0.412453 * r + 0.357580 * g + 0.180423 * b) / 0.950456
    y = 0.212671 * r + 0.715160 * g + 0.072169 * b

    def f(t):
        return np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)

    return 500.0 * (f(x) - f(y))


@pytest.mark.parametrize("rgb, a_star", [
    ((0, 255, 0), -86.18),  # sRGB primaries and secondaries (published D65 values)
    ((255, 0, 0), 80.09),
    ((0, 0, 255), 79.19),
    ((255, 255, 0), -21.55),
    ((255, 0, 255), 98.23),
    ((128, 128, 128), 0.0),
    ((0, 0, 0), 0.0),
])
def test_published_colours(rgb, a_star) -> None:
    bgr = np.array(rgb[::-1], np.uint8).reshape(1, 1, 3)
    got = float(neg_a_star(bgr, np.ones(3))[0, 0])
    assert got == pytest.approx(-a_star / 100.0, abs=0.002)
    assert float(vegetation_index(bgr, gains=np.ones(3, np.float32), lab=True)[0, 0]) == got


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.uint8, (7, 9, 3)), st.tuples(*[st.floats(0.5, 2.0)] * 3))
def test_tables_match_the_formulas(bgr, gains) -> None:
    """The 8-bit path (per-channel tables, in-place cube roots, CIE's linear branch for dark colours)
    and the float path give CIE's a* of the white-balanced colour, clipped to white."""
    g = np.array(gains)
    want = -_a_star_reference(bgr[..., ::-1].astype(np.float64) * g[::-1] / 255.0) / 100.0
    got8 = neg_a_star(bgr, g)
    gotf = neg_a_star(bgr.astype(np.float32), g)
    assert np.array_equal(neg_a_star(bgr, g), got8)  # again, from the cached table
    assert got8.dtype == np.float32 and got8.shape == bgr.shape[:2]
    np.testing.assert_allclose(got8, want, atol=2e-5)
    np.testing.assert_allclose(gotf, want, atol=2e-5)


def test_dark_colours_take_the_linear_branch() -> None:
    """Below (6/29)³ in X/Xn or Y, f is linear: a cube root there would put a dark green shadow far
    from its lit colour's a*."""
    bgr = np.array([[[0, 6, 0], [2, 9, 1], [0, 0, 7]]], np.uint8)
    want = -_a_star_reference(bgr[..., ::-1] / 255.0) / 100.0
    got = neg_a_star(bgr, np.ones(3))
    np.testing.assert_allclose(got, want, atol=2e-5)
    y = 0.715160 * (6 / 255 / 12.92)  # what a cube root alone would give for the first pixel
    x = 0.357580 * (6 / 255 / 12.92) / 0.950456
    assert abs(float(got[0, 0]) - (-5.0 * (np.cbrt(x) - np.cbrt(y)))) > 0.01


@st.composite
def _frames(draw):
    h, w = draw(st.integers(1, 40)), draw(st.integers(1, 40))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    img = rng.integers(0, 256, (h + 4, w + 4, 3), dtype=np.uint8)
    layout = draw(st.sampled_from(["c", "view", "fortran", "readonly"]))
    if layout == "view":  # a crop of a larger frame: rows not contiguous
        img = img[2:2 + h, 1:1 + w]
    elif layout == "fortran":
        img = np.asfortranarray(img)
    elif layout == "readonly":
        img.flags.writeable = False
    return img, np.array(draw(st.lists(st.floats(0.5, 2.0), min_size=3, max_size=3)), np.float32)


@settings(max_examples=200, deadline=None)
@given(_frames())
def test_gstar_compiled_loop_equals_its_fallback_in_any_layout(args) -> None:
    """The compiled loop (`_gstar_u8`) and its fallback (the planes split and scaled by table
    lookup, as where numba cannot compile) give the float path's G* (the image scaled to float by
    `cv2.multiply`) to the last bit, and the definition (G − max(R, B))/(B + G + R + 30) of the
    scaled channels within float32 rounding: the tables are a speed-up that must not move an answer."""
    img, gains = args
    got = vegetation_index(img, gains=gains)
    assert got.dtype == np.float32 and got.shape == img.shape[:2]
    want = greenness(_scaled(np.ascontiguousarray(img), gains))
    assert np.array_equal(got, want)
    b, g, r = (img[..., k].astype(np.float64) * float(gains[k]) for k in range(3))
    np.testing.assert_allclose(got, (g - np.maximum(r, b)) / (b + g + r + 30.0), atol=1e-6)
    compiled = veg._gstar_u8
    try:
        veg._gstar_u8 = None
        assert np.array_equal(vegetation_index(img, gains=gains), want)
    finally:
        veg._gstar_u8 = compiled
