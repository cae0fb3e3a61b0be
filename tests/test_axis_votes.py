"""The leaf-axis vote accumulator (`axis_votes.line_votes`): the compiled loop against its numpy
fallback (the formulation the detector used before: every line's points as one (n, 2L + 1) index
array, summed by `np.bincount`). They must give the same map to the last bit (same float32
rounding of the points, same summation order), so the detector's answers do not depend on which
one ran.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capm_field import axis_votes as av
from capm_field.axis_votes import axis_votes, line_votes


@st.composite
def vote_inputs(draw):
    h, w = draw(st.integers(1, 60)), draw(st.integers(1, 60))
    n = draw(st.integers(0, 40))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    # starts on the grid and a little off it; any direction; weights of any spread
    xs = rng.integers(-5, w + 5, n).astype(np.int64)
    ys = rng.integers(-5, h + 5, n).astype(np.int64)
    phi = rng.uniform(-np.pi, np.pi, n)
    dx, dy = np.cos(phi).astype(np.float32), np.sin(phi).astype(np.float32)
    wts = rng.exponential(1.0, n) * 10.0 ** rng.uniform(-6, 3, n)
    L = draw(st.integers(0, 80))
    return xs, ys, dx, dy, wts, L, h, w


@settings(max_examples=300, deadline=None)
@given(vote_inputs())
def test_line_votes_equal_numpy_to_the_last_bit(args) -> None:
    got = av._line_votes_loop(*args)
    want = av._line_votes_numpy(*args)
    assert got.dtype == np.float64 and got.shape == want.shape
    assert np.array_equal(got, want)


def test_line_votes_axis_aligned_and_diagonal_lines() -> None:
    # a horizontal line through (2, 1) of half-length 2 on a 5 × 3 grid: (0..4, 1), weight 1.5
    one = line_votes(np.array([2]), np.array([1]), np.array([1.0], np.float32), np.array([0.0], np.float32),
                     np.array([1.5]), 2, 3, 5).reshape(3, 5)
    want = np.zeros((3, 5))
    want[1, :] = 1.5
    assert np.array_equal(one, want)
    # two diagonal lines crossing at (2, 2): their crossing pixel gets both weights, the rest one
    d = np.float32(np.sqrt(0.5))
    two = line_votes(np.array([2, 2]), np.array([2, 2]), np.array([d, d], np.float32),
                     np.array([d, -d], np.float32), np.array([1.0, 2.0]), 1, 5, 5).reshape(5, 5)
    assert two[2, 2] == 3.0
    assert two.sum() == 3 * 1.0 + 3 * 2.0


@pytest.mark.parametrize("compiled", [True, False])
def test_axis_votes_of_a_fan_peak_at_its_base(compiled: bool, monkeypatch) -> None:
    # five blades fanning up from one base: the votes pile up where their axes meet
    if not compiled:
        monkeypatch.setattr(av, "_line_votes_loop", None)  # as where numba cannot compile
    vi = np.zeros((120, 120), np.float32)
    base = (60, 100)
    for ang in np.radians([-50, -25, 0, 25, 50]):
        tip = (int(60 + 80 * np.sin(ang)), int(100 - 80 * np.cos(ang)))
        cv2.line(vi, base, tip, 0.3, 3)
    votes = axis_votes(vi, vi > 0.1, 100.0)
    iy, ix = np.unravel_index(int(np.argmax(votes)), votes.shape)
    assert votes.max() == 1.0
    assert np.hypot(ix - base[0], iy - base[1]) < 8
