"""Stage 2's line-of-sight check (`star_centre`): the share of a plant seen from a point along
straight lines on the plant, the compiled loop against its numpy formulation, the star centre of
drawn plants, and two bench rosettes whose answer it moves from a leaf back to the centre
(docs/perception.md §2, stage 2)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import capm_field.centre_cascade as cascade
from capm_field import star_centre as sc
from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.detector import detect_centre, ground_centre, roi_from_troi
from sim_bench.perception_bench import make_case

CAM = PinholeCamera.from_config(CameraConfig())


def _rosette(n: int = 5, length: float = 32.0, c=(50, 50), shape=(100, 100), gap: int = 0, half_width: int = 3) -> np.ndarray:
    """Leaves (ellipses) radiating from c; `gap` px of soil between the centre and each leaf."""
    m = np.zeros(shape, np.uint8)
    for k in range(n):
        a = 2 * math.pi * k / n + 0.3
        mid = (c[0] + (gap + length / 2) * math.cos(a), c[1] + (gap + length / 2) * math.sin(a))
        cv2.ellipse(m, (round(mid[0]), round(mid[1])), (round(length / 2), half_width), math.degrees(a), 0, 360, 1, -1)
    return m.astype(bool)


@st.composite
def masks_and_points(draw):
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    h, w = draw(st.integers(4, 70)), draw(st.integers(4, 70))
    m = np.zeros((h, w), np.uint8)
    for _ in range(draw(st.integers(1, 6))):
        cv2.ellipse(m, (int(rng.integers(0, w)), int(rng.integers(0, h))), (int(rng.integers(1, 20)), int(rng.integers(1, 8))),
                    float(rng.uniform(0, 180)), 0, 360, 1, -1)
    plant = m.astype(bool)
    if not plant.any():
        plant[h // 2, w // 2] = True
    C = np.r_[sc._candidates(plant, sc.STRIDE), rng.uniform(-2, max(h, w) + 2, (5, 2)).astype(np.float32)]
    return sc._grown(plant), np.ascontiguousarray(C, np.float32), sc._targets(plant)


@pytest.mark.skipif(sc._seen_loop is None, reason="numba cannot compile here")
@settings(max_examples=150, deadline=None)
@given(masks_and_points())
def test_compiled_loop_equals_numpy_to_the_last_bit(args) -> None:
    grown, C, T = args
    got = sc._seen_loop(grown.astype(np.uint8), C, T, sc._tk())
    want = sc._seen_numpy(grown, C, T)
    assert got.dtype == np.float32 and np.array_equal(got, want)


def test_the_centre_of_a_rosette_sees_it_all_and_a_leaf_tip_little() -> None:
    plant = _rosette()
    assert sc.visibility(plant, np.array([50.0, 50.0])) > 0.95
    tip = np.array([50 + 30 * math.cos(0.3), 50 + 30 * math.sin(0.3)])
    assert sc.visibility(plant, tip) < sc.LOW


def test_an_answer_on_a_broad_leaf_near_the_centre_is_kept() -> None:
    """Broad leaves overlapping at the centre: from a leaf's tip over half the plant is in sight,
    so the check leaves the estimators' answer (it moves only answers that see < LOW of it)."""
    plant = _rosette(5, half_width=5)
    tip = np.array([50 + 28 * math.cos(0.3), 50 + 28 * math.sin(0.3)])
    assert sc.visibility(plant, tip) >= sc.LOW
    assert sc.star_check(plant, tip) is None


@pytest.mark.parametrize("n", [3, 5, 8])
def test_an_answer_on_a_leaf_goes_back_to_the_centre(n: int, monkeypatch) -> None:
    """Compiled and in numpy: the same point."""
    plant = _rosette(n)
    tip = np.array([50 + 28 * math.cos(0.3), 50 + 28 * math.sin(0.3)])
    got = sc.star_check(plant, tip)
    assert got is not None and np.hypot(*(got - 50.0)) < 2.5
    monkeypatch.setattr(sc, "_seen_loop", None)  # as where numba cannot compile
    assert np.array_equal(sc.star_check(plant, tip), got)


def test_an_answer_at_the_centre_is_kept() -> None:
    assert sc.star_check(_rosette(), np.array([50.0, 50.0])) is None


def test_a_plant_that_is_not_star_shaped_is_left_to_the_estimators() -> None:
    """Leaves apart from a centre the mask does not hold (a clover whose petioles the threshold
    missed): no point sees ≥ STAR_MIN of it, so even an answer on one leaf stays."""
    plant = _rosette(4, length=24, gap=10)
    leaf = np.array([50 + 22 * math.cos(0.3), 50 + 22 * math.sin(0.3)])
    assert sc.visibility(plant, leaf) < sc.LOW
    assert sc.star_point(plant)[1] < sc.STAR_MIN
    assert sc.star_check(plant, leaf) is None


def test_empty_and_huge_masks_give_no_star() -> None:
    assert sc.visibility(np.zeros((10, 10), bool), np.array([5.0, 5.0])) == 0.0
    assert sc.star_point(np.zeros((10, 10), bool)) is None
    assert sc.star_check(np.zeros((10, 10), bool), np.array([5.0, 5.0])) is None
    assert sc.star_point(np.ones((200, 200), bool)) is None  # over MAX_CANDIDATES


@pytest.mark.parametrize("seed, index", [(10, 88), (11, 208)])
def test_bench_rosettes_answered_on_a_leaf_midrib_are_moved_to_their_centre(seed: int, index: int, monkeypatch) -> None:
    """Two bench rosettes (seeds 10 and 11) whose `petiole_centre` met a leaf's midrib 101–113 mm
    from the centre: within 10 mm with the check, over 30 mm without it."""
    case = make_case(seed, index, CAM, TaskConfig().delta, False)
    img = case.scene.render(case.T, CAM)
    roi = roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius)

    def err_mm() -> float:
        det = detect_centre(img, roi)
        assert det.reason is None
        return float(np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre)) * 1000

    assert err_mm() < 10.0
    monkeypatch.setattr(cascade, "STAR_CHECK", False)
    assert err_mm() > 30.0
