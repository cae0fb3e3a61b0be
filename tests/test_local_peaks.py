"""`local_peaks.disc_peaks`: the compiled loop gives OpenCV's formulation (candidates & img ≥ its dilation
by the elliptic disc, the outside ignored) pixel for pixel, on maps with plateaus and peaks at the border."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from capm_field import local_peaks
from capm_field.local_peaks import disc_peaks


def _opencv(img: np.ndarray, cand: np.ndarray, r: int) -> np.ndarray:
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cand & (img >= cv2.dilate(img, disc))


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 70), w=st.integers(1, 70), r=st.integers(1, 16),
       levels=st.integers(2, 1000), sigma=st.floats(0.0, 4.0), share=st.floats(0.0, 1.0))
def test_compiled_peaks_equal_opencv_dilation(seed, h, w, r, levels, sigma, share) -> None:
    rng = np.random.default_rng(seed)
    img = rng.random((h, w)).astype(np.float32)
    if sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    img = (np.round(img * levels) / levels).astype(np.float32)  # plateaus: ties between neighbours
    cand = rng.random((h, w)) < share
    got = disc_peaks(img, cand, r)
    assert got.dtype == bool and got.shape == (h, w)
    assert np.array_equal(got, _opencv(img, cand, r))


def test_a_single_peak_and_a_plateau() -> None:
    img = np.zeros((20, 30), np.float32)
    img[5, 5] = 1.0
    img[15, 20:23] = 0.5  # a plateau: every pixel of it is a peak (≥ its neighbours)
    peaks = disc_peaks(img, img > 0, 3)
    assert peaks[5, 5] and peaks[15, 20:23].all() and peaks.sum() == 4
    img[15, 25] = 0.6  # within the disc of the plateau's right end only
    peaks = disc_peaks(img, img > 0, 3)
    assert not peaks[15, 22] and peaks[15, 20:22].all() and peaks[15, 25]


def test_without_the_compiled_loop_opencv_answers_the_same(monkeypatch) -> None:
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.random((50, 60)).astype(np.float32), (0, 0), 2)
    cand = img > np.quantile(img, 0.7)
    compiled = disc_peaks(img, cand, 6)
    monkeypatch.setattr(local_peaks, "_disc_peaks_loop", None)
    assert np.array_equal(disc_peaks(img, cand, 6), compiled)
    # other dtypes take the OpenCV formulation in their own precision
    assert np.array_equal(disc_peaks(img.astype(np.float64), cand, 6), compiled)


def test_the_loop_is_compiled_here() -> None:
    assert local_peaks._disc_peaks_loop is not None
