"""`capm_field.line_strength`: the compiled line filter gives the numpy formulation's values, and
finds a straight stalk's direction on textured soil."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capm_field import line_strength as ls


def _soil_with_stalks(seed: int, h: int, w: int, angles: list[float]) -> np.ndarray:
    """Grey float32 image: textured soil (noise at two scales) crossed by thin dark and light lines."""
    rng = np.random.default_rng(seed)
    img = rng.normal(0.45, 0.04, (h, w)).astype(np.float32)
    img += cv2.resize(rng.normal(0, 0.06, (h // 8 + 1, w // 8 + 1)).astype(np.float32), (w, h))
    for k, a in enumerate(angles):
        c = (w / 2 + rng.uniform(-w / 6, w / 6), h / 2 + rng.uniform(-h / 6, h / 6))
        d = 0.45 * min(h, w)
        p0 = (int(c[0] - d * math.cos(a)), int(c[1] - d * math.sin(a)))
        p1 = (int(c[0] + d * math.cos(a)), int(c[1] + d * math.sin(a)))
        cv2.line(img, p0, p1, 0.2 if k % 2 == 0 else 0.7, int(rng.integers(1, 3)), cv2.LINE_AA)
    return img


def test_the_detectors_line_loops_are_compiled_here() -> None:
    assert ls._pixel_lines is not None and ls._tensor_lines is not None


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), h=st.integers(12, 160), w=st.integers(12, 160),
       angles=st.lists(st.floats(0.0, math.pi), min_size=0, max_size=3), length=st.floats(2.0, 30.0))
def test_compiled_line_filter_matches_the_numpy_formulation(seed, h, w, angles, length) -> None:
    grey = _soil_with_stalks(seed, h, w, angles)
    best, idx, own = ls.line_strength(grey, length)
    best0, idx0, own0 = ls.line_strength(grey, length, compiled=False)
    assert best.dtype == best0.dtype == own.dtype == np.float32 and idx.dtype == idx0.dtype == np.uint8
    scale = max(float(best0.max()), 1e-6)
    np.testing.assert_allclose(best, best0, rtol=0, atol=1e-5 * scale)
    np.testing.assert_allclose(own, own0, rtol=0, atol=1e-5 * max(float(own0.max()), 1e-6))
    # the direction bin differs only at a tie (or where there is no direction to speak of)
    differ = (idx != idx0) & (best0 > 1e-4 * scale)
    assert np.count_nonzero(differ) <= max(2, idx.size // 5000)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_straight_stalk_on_soil_reads_as_its_direction(compiled: bool) -> None:
    a = math.radians(30)
    grey = _soil_with_stalks(3, 120, 140, [a])
    best, idx, own = ls.line_strength(grey, 15.0, compiled=compiled)
    strong = best >= np.percentile(best, 99)
    bins = np.bincount(idx[strong], minlength=ls.N_DIRS)
    expect = int(round(a / (math.pi / ls.N_DIRS))) % ls.N_DIRS
    # the strongest agreeing pixels are on the line and point along it (± one bin)
    assert bins[[expect - 1, expect, (expect + 1) % ls.N_DIRS]].sum() >= 0.8 * strong.sum()
